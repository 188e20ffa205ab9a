"""One report writer for every study.

A study module computes what is its own: its tables, its verdicts, the text of its claims and
which figures it draws. It hands them over as a :class:`Report`, and the code here does what every
study does alike:

* :func:`write` puts a report in a folder: each table (CSV or Parquet, by its file name) and text
  file, ``study.json`` (the study, its parameters, the package's version and source hash, the
  number of runs), then the figures, the forest plot of the verdicts last. Figures are written
  without a date and with fixed SVG ids, so the same report is the same bytes.
* :func:`run_and_report` runs a study's configs and writes its report through
  :class:`gimbal_lab.outputs.ReportFolder`, with a progress line for every step that takes time.
* :func:`measured_once` keeps a measurement that is not a run (the pipelines' CPU cost per frame)
  in the store beside the runs, with the machine it was measured on: a rerun over the same runs
  reads it, so its tables and claims are the same bytes.
* :func:`summary_lines` is what the terminal gets at the end: the tally at both levels, the
  conditions that do not hold or are inconclusive, and the path of ``claims.md``.
"""

from __future__ import annotations

import hashlib
import json
import os
import platform
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

__all__ = ["Report", "write", "run_and_report", "measured_once", "summary_lines", "say", "FIGURE_DPI",
           "MEASUREMENTS"]

#: Resolution of the report's PNG figures, dots per inch.
FIGURE_DPI = 120
#: Folder of the store (beside ``runs``) that keeps the measurements of :func:`measured_once`.
MEASUREMENTS = "measurements"
_MEASUREMENT_FORMAT = 1
#: Conditions that do not hold or are inconclusive listed on the terminal; claims.md lists all.
SUMMARY_ROWS = 8


def say(text: str, progress: bool = True) -> None:
    """A progress line on stderr (where the progress bars go), when ``progress``."""
    if progress:
        print(text, file=sys.stderr, flush=True)


@dataclass
class Report:
    """What a study hands to :func:`write`.

    Parameters
    ----------
    study : str
        The study's name (``study.json``'s ``study``; a scenario's own name).
    params : StudyParams
        Its parameters (``to_dict()`` goes to ``study.json``).
    runs : int
        The number of runs the report is made of.
    files : list of (str, DataFrame or str)
        Each file of the report in the order written: a DataFrame goes to ``NAME.csv`` or
        ``NAME.parquet`` without its index, a string to a text file (``claims.md``).
    figures : list of (str, callable)
        ``(name, draw)``: ``draw()`` returns a matplotlib Figure or Axes, saved as
        ``figures/NAME.FORMAT``; drawn one at a time, when written.
    verdicts : DataFrame, optional
        The verdict table (:func:`gimbal_lab.stats.verdict_table` columns): the forest plot and
        the terminal's summary.
    forest : str or None
        The forest plot's figure name; None for none. It shows ``forest_rows`` (default: every
        verdict) and is left out when there are none.
    forest_rows : DataFrame, optional
        The verdicts the forest plot shows, when not all of them.
    formats : tuple of str
        The figures' formats.
    """

    study: str
    params: object
    runs: int
    files: list
    figures: list = field(default_factory=list)
    verdicts: object = None
    forest: str | None = "hypotheses_forest"
    forest_rows: object = None
    formats: tuple = ("png", "svg")

    def all_figures(self) -> list[tuple[str, Callable]]:
        """The study's figures followed by the forest plot (when there are verdicts to show)."""
        rows = self.verdicts if self.forest_rows is None else self.forest_rows
        if self.forest is None or rows is None or not len(rows):
            return list(self.figures)

        def forest():
            from ..plotting.study import plot_forest

            return plot_forest(rows)

        return list(self.figures) + [(self.forest, forest)]


def _write_file(path: Path, content) -> None:
    if isinstance(content, str):
        path.write_text(content)
    elif path.suffix == ".parquet":
        content.to_parquet(path, index=False)
    elif path.suffix == ".csv":
        content.to_csv(path, index=False)
    else:
        raise ValueError(f"a report table is written as .csv or .parquet, got {path.name}")


def _save_figure(fig, name: str, folder: Path, formats) -> list[Path]:
    """``fig`` as ``folder/NAME.FORMAT`` for each format: the same figure gives the same bytes (no
    date in the SVG, its ids salted with the file's name instead of a random number)."""
    import matplotlib

    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for fmt in formats:
        path = folder / f"{name}.{fmt}"
        metadata = {"Date": None} if fmt in ("svg", "pdf") else None
        with matplotlib.rc_context({"svg.hashsalt": name}):
            fig.savefig(path, dpi=FIGURE_DPI, bbox_inches="tight", metadata=metadata)
        paths.append(path)
    return paths


def write(folder, report: Report, progress: bool = False) -> list[Path]:
    """Write ``report`` into ``folder`` (created if needed); return the paths written, in order.

    Files: each of ``report.files``, ``study.json``, then ``figures/NAME.FORMAT`` for each figure
    (:meth:`Report.all_figures`), each closed once saved. With ``progress``, a bar over the figures.
    """
    from .. import __version__
    from ..runner import source_hash
    from ._params import report_pyplot

    plt = report_pyplot()
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    written = []
    for name, content in report.files:
        _write_file(folder / name, content)
        written.append(folder / name)
    meta = {"study": report.study, "parameters": report.params.to_dict(), "package_version": __version__,
            "source_hash": source_hash(), "runs": report.runs}
    (folder / "study.json").write_text(json.dumps(meta, indent=1))
    written.append(folder / "study.json")
    figures = report.all_figures()
    bar = None
    if progress and figures:
        from tqdm.auto import tqdm

        bar = tqdm(total=len(figures), desc=f"{report.study} figures", unit="figure", dynamic_ncols=True)
    try:
        for name, draw in figures:
            if bar is not None:
                bar.set_postfix_str(name)
            drawn = draw()
            fig = drawn if isinstance(drawn, plt.Figure) else drawn.figure
            written += _save_figure(fig, name, folder / "figures", report.formats)
            plt.close(fig)
            if bar is not None:
                bar.update(1)
    finally:
        if bar is not None:
            bar.close()
        plt.close("all")
    return written


# ----------------------------------------------------------------------------------------------
# a measurement kept with the runs it was made on
# ----------------------------------------------------------------------------------------------
def machine() -> dict:
    """The machine a measurement was made on: host name, CPU model, CPU count, system."""
    model = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return {"host": platform.node(), "cpu": model, "cpus": os.cpu_count(), "system": platform.platform()}


def _measurement_key(what: str, runs) -> str:
    from ..runner import ResultsStore

    text = json.dumps({"format": _MEASUREMENT_FORMAT, "what": what,
                       "runs": sorted(ResultsStore.key(r.config) for r in runs)}, sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:24]


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def measured_once(store, runs, what: str, measure: Callable, progress: bool = False):
    """``measure()`` (a DataFrame) made once per set of runs and kept in ``store``.

    The table goes to ``store.root/measurements/KEY.parquet`` with a sidecar ``KEY.json`` naming
    what was measured, the machine (:func:`machine`), the time and the table's SHA-256; KEY is a
    SHA-256 of ``what`` and the runs' store keys (each run's config and the package's source hash),
    so a changed run or code measures again. A later call with the same runs reads the table (from
    any machine: the sidecar says which one measured it) unless the store does not read
    (``--no-cache``), and a sidecar or table that does not match is measured again.

    Parameters
    ----------
    store : ResultsStore or None
        None: measure, keep nothing.
    runs : sequence of TrackingResult
        The runs the measurement is made on.
    what : str
        What is measured, with every setting that changes it (e.g. the passes).
    measure : callable
        ``measure()`` returns the DataFrame.
    """
    import pandas as pd

    from ..outputs import atomic_path

    if store is None:
        say(f"measuring {what} ...", progress)
        return measure()
    folder = Path(store.root) / MEASUREMENTS
    key = _measurement_key(what, runs)
    table, sidecar = folder / f"{key}.parquet", folder / f"{key}.json"
    if store.read:
        try:
            meta = json.loads(sidecar.read_text())
            if meta.get("format") == _MEASUREMENT_FORMAT and meta.get("sha256") == _sha256(table):
                host = meta.get("machine", {})
                say(f"{what}: measured on {host.get('host', '?')} ({host.get('cpu', '?')}) at "
                    f"{meta.get('measured_utc', '?')}, read from {table}", progress)
                return pd.read_parquet(table)
        except (OSError, ValueError, AttributeError):
            pass
    say(f"measuring {what} (once for these runs; kept in {folder}) ...", progress)
    result = measure()
    folder.mkdir(parents=True, exist_ok=True)
    with atomic_path(table) as tmp:
        result.to_parquet(tmp, index=False)
    meta = {"format": _MEASUREMENT_FORMAT, "what": what, "runs": len(runs), "machine": machine(),
            "load_1min": os.getloadavg()[0], "measured_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
            "sha256": _sha256(table)}
    with atomic_path(sidecar) as tmp:
        tmp.write_text(json.dumps(meta, indent=1) + "\n")
    return result


# ----------------------------------------------------------------------------------------------
# running a study and writing its report; the terminal's summary
# ----------------------------------------------------------------------------------------------
def run_and_report(name: str, desc: str, configs, make_report, study, out, *, store=None, executor=None, jobs=None,
                   progress=True, extra=None) -> dict:
    """Run ``configs`` (reusing ``store``), then write the study's report into ``out/name``.

    ``make_report(results, study)`` returns the study's :class:`Report`; it and ``extra(folder,
    results, study)`` when given (the clips) write into a staging folder whose files then replace
    those of ``out/name``, a folder the lab manages (:class:`gimbal_lab.outputs.ReportFolder`): a
    folder holding files the lab did not write is refused before any run, nothing else is deleted,
    and files of an earlier report that this one does not write are kept. With ``progress``, each
    step says what it does. Returns a dict with the results, the verdicts, the folder, the paths
    written and the paths kept.
    """
    from ..outputs import ReportFolder
    from ..runner import run

    folder = ReportFolder(Path(out) / name, "the report folder")
    folder.check()  # before the runs
    say(f"{name}: reading the stored runs, computing the others ...", progress)
    results = run(configs, store=store, executor=executor, jobs=jobs, progress=progress, desc=desc)
    say(f"{name}: tables and verdicts of {len(results)} runs ...", progress)
    report = make_report(results, study)
    with folder.staging() as tmp:
        say(f"{name}: writing {len(report.files) + 1} tables and files and {len(report.all_figures())} figures ...",
            progress)
        write(tmp, report, progress=progress)
        if extra is not None:
            extra(tmp, results, study)
        say(f"{name}: replacing the report's files in {folder.path} ...", progress)
    return {"results": results, "verdicts": report.verdicts, "folder": folder.path, "written": folder.written,
            "kept": folder.kept}


def run_with_choices(name: str, label: str, calibration_configs, plan_tests, make_report, study, out, *,
                     store=None, executor=None, jobs=None, progress=True) -> dict:
    """A study whose pipelines choose on calibration runs before it tests them: the calibration
    runs, ``plan_tests(calibration_results)`` → (the test runs' index, their configs), then the
    test runs and the report, as :func:`run_and_report` writes it, in ``out/name``.

    ``make_report(calibration_results, index, test_results, study)`` returns the :class:`Report`.
    The report folder is checked before the calibration runs; progress bars read "LABEL:
    calibration" and "LABEL: test"."""
    from ..outputs import ReportFolder
    from ..runner import run

    ReportFolder(Path(out) / name, "the report folder").check()  # before the calibration runs
    calibration = run(calibration_configs, store=store, executor=executor, jobs=jobs, progress=progress,
                      desc=f"{label}: calibration")
    index, test_configs = plan_tests(calibration)

    def report(test_results, params):
        return make_report(calibration, index, test_results, params)

    return run_and_report(name, f"{label}: test", test_configs, report, study, out, store=store, executor=executor,
                          jobs=jobs, progress=progress)


def summary_lines(verdicts, claims_path, most: int = SUMMARY_ROWS) -> list[str]:
    """The terminal's summary of a report: the tally of the verdicts at both levels, up to ``most``
    conditions that do not hold or are inconclusive (one line each), and where ``claims.md`` is."""
    from .. import stats
    from ._params import verdict_counts

    if verdicts is None or not len(verdicts):
        return ["No hypotheses to check: claims.md holds the measured cells.", f"Claims: {claims_path}"]
    lines = [verdict_counts(verdicts)]
    failing = verdicts[verdicts["verdict"] != stats.HOLDS]
    if len(failing):
        shown = f" (the first {most})" if len(failing) > most else ""
        lines.append(f"Not holding or inconclusive at 95 %{shown}:")
        holm = "verdict_holm" in verdicts
        for row in failing.head(most).itertuples():
            family = f"; {row.verdict_holm} in the family" if holm else ""
            lines.append(f"  {row.id} {row.condition}: {row.a} vs {row.b}: {row.verdict}{family}")
        if len(failing) > most:
            lines.append(f"  ... and {len(failing) - most} more")
    lines.append(f"Claims, reasons and every table: {claims_path}")
    return lines
