"""Settings for the whole test run (unit tests and notebooks), in one process or under pytest-xdist.

* One BLAS thread, static widgets, 3 replicates per cell in the extension notebooks (below).
* **The suite's own results store.** The notebooks and the tests keep their runs in a store made
  for this test run (a temporary folder, deleted at the end), never in the user's
  (``results/store``, ``$GIMBAL_LAB_STORE``, the user's cache folder): a test run checks the
  science computed by the code under test. The
  store's keys hold the package's source hash, so a user's entry can never be stale code, but
  they do not hold the versions of numpy, OpenCV or Mesa that computed it, and a test must not
  pass on a run made before an upgrade. Set ``GIMBAL_LAB_TEST_STORE=PATH`` to keep the suite's
  store in PATH and reuse it in the next test run (reruns of one notebook while editing it).
  Every test and notebook runs with ``GIMBAL_LAB_STORE`` set to that store (a test of the store's
  location, or one that needs a store of its own, sets or removes it).
  Under pytest-xdist every worker uses the one store the controlling process made, so notebooks
  07 and 08 share their paper runs there; the store's claims (``gimbal_lab.runner.ResultsStore``)
  keep two workers from computing one run twice.
* **Worker processes.** Under ``pytest -n N`` each xdist worker's sweeps start ``CPUs // N``
  local workers (``GIMBAL_LAB_JOBS``, read by ``gimbal_lab.runner.default_jobs``), not one per
  CPU each.
* **Time budget.** The wall time of each test file and notebook is summed; at the end, only when
  the whole run took longer than the total of ``benchmarks/suite_budget.toml`` (25 minutes on a
  loaded 2-core machine), the files over their share are named (a note, never a failure: speed is
  measured, not asserted). ``--time-budget`` prints every file's time whatever the total.
* **Ctrl-C reaches the commands under test.** A shell starts a background job (``pytest &`` in a
  script) with SIGINT ignored, and a child process inherits an ignored signal across ``exec``: the
  tests that press Ctrl-C on a command would then wait for an exit that never comes. Each process
  of the run (the controller and every xdist worker) catches SIGINT again, so the commands it starts
  get the default disposition.
"""

import fnmatch
import os
import resource
import shutil
import signal
import sys
import tempfile
import time
import tomllib
from collections import defaultdict
from pathlib import Path

import pytest

# GIMBAL_LAB_OTHER_CPU=1 runs the tests as on another x86-64 CPU: the libraries pick their kernels
# per CPU at run time, and an iterative or ill-conditioned computation's last digits follow the
# kernels (issue 26). Set before numpy and OpenCV are loaded, in this process and in the notebook
# kernels and workers it starts: OpenCV's dispatched code at its SSE3 baseline and Intel IPP off,
# numpy's SIMD loops at their baseline, OpenBLAS's generic SSE3 kernels. Each can also be set by
# hand, and so can a BLAS thread count other than 1 (OPENBLAS_NUM_THREADS=2 splits BLAS sums
# differently, but the study workers then run two BLAS threads each beside their renderer).
if os.environ.get("GIMBAL_LAB_OTHER_CPU", "0") not in ("", "0"):
    if "numpy" in sys.modules or "cv2" in sys.modules:
        raise RuntimeError("GIMBAL_LAB_OTHER_CPU must take effect before numpy and cv2 are imported")
    os.environ.setdefault("OPENCV_CPU_DISABLE", "SSE4.1,SSE4.2,AVX,FP16,AVX2,AVX512-SKX")
    os.environ.setdefault("OPENCV_IPP", "disabled")
    os.environ.setdefault("NPY_DISABLE_CPU_FEATURES", "X86_V3 X86_V4 AVX512_ICL AVX512_SPR")
    os.environ.setdefault("OPENBLAS_CORETYPE", "Prescott")
    import cv2

    cv2.setUseOptimized(False)  # this process: IPP, dispatch and OpenCL off at once

# One BLAS thread in this process and in the notebook kernels it starts (before numpy is
# imported): the matrices are small and a second thread beside the renderer only spins
# (gimbal_lab.runner.CHILD_THREAD_LIMITS; the study workers get the same limits anyway).
for _name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_name, "1")

# Notebooks draw their interactive explorers once, statically (gimbal_lab.plotting.interactive):
# the kernels nbmake starts inherit this environment.
os.environ.setdefault("GIMBAL_LAB_WIDGETS", "0")

# The study notebooks (07 onwards) run 2 replicates per cell under the test suite instead of the
# studies' declared 10: the fewest that give a paired interval. Same code, fewer replicates (and
# below 10, notebooks 09, 10 and 15 run a subset of their cells, and 07, 08 and 10 time each
# pipeline's cost in one pass over every 4th measured frame instead of 5 passes over every frame:
# each parameters cell says which); their closing checks
# hold at any count. Set GIMBAL_LAB_REPLICATES=10 before `pytest` to test the full size (then every
# notebook runs it).
_SUITE_REPLICATES = "2"
# set by the user before `pytest` (xdist's workers inherit the controller's default and its mark)
_user_replicates = (bool(os.environ.get("GIMBAL_LAB_REPLICATES", "").strip())
                    and os.environ.get("_GIMBAL_LAB_SUITE_REPLICATES") != "1")
if not _user_replicates:
    os.environ["GIMBAL_LAB_REPLICATES"] = _SUITE_REPLICATES
    os.environ["_GIMBAL_LAB_SUITE_REPLICATES"] = "1"

ROOT = Path(__file__).resolve().parent
#: The user's store never reaches the suite (see the module's docstring).
STORE_ENV, TEST_STORE_ENV, JOBS_ENV = "GIMBAL_LAB_STORE", "GIMBAL_LAB_TEST_STORE", "GIMBAL_LAB_JOBS"
os.environ.pop(STORE_ENV, None)
BUDGET_FILE = ROOT / "benchmarks" / "suite_budget.toml"

_made_store: Path | None = None  # the store this process made (the controlling one), deleted at the end
_seconds: dict[str, float] = defaultdict(float)  # test file or notebook -> setup + call + teardown, s
_cpu_seconds: dict[str, float] = defaultdict(float)  # the same, CPU time of the test process and its children
_started: dict[str, float] = {}


def pytest_addoption(parser):
    parser.addoption("--time-budget", action="store_true",
                     help="print every test file's and notebook's time beside its budget (benchmarks/suite_budget.toml)")


def pytest_configure(config):
    global _made_store
    if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:  # see "Ctrl-C reaches the commands under test"
        signal.signal(signal.SIGINT, signal.default_int_handler)
    worker = getattr(config, "workerinput", None)
    if worker is None:  # this process collects and reports; xdist's workers start later and inherit os.environ
        if not os.environ.get(TEST_STORE_ENV, "").strip():
            _made_store = Path(tempfile.mkdtemp(prefix="gimbal-lab-test-store-"))
            os.environ[TEST_STORE_ENV] = str(_made_store)
        _started.update(wall=time.time(), load=os.getloadavg()[0])
    else:
        # at least 2: a notebook's study sweep with one local worker leaves a core idle whenever
        # the other xdist worker has nothing left to run (measured: the moving-drone notebook ran
        # alone on one core for its last 25 minutes); two per worker oversubscribe 2 cores twice,
        # which costs little for CPU-bound rendering
        share = max(2, (os.cpu_count() or 1) // int(worker["workercount"]))
        os.environ.setdefault(JOBS_ENV, str(share))


def pytest_unconfigure(config):
    if _made_store is not None:
        shutil.rmtree(_made_store, ignore_errors=True)


def _is_notebook(item) -> bool:
    return Path(str(item.path)).suffix == ".ipynb"


# ----------------------------------------------------------------------------------------------
# order: the long notebooks first, dealt over the xdist workers
# ----------------------------------------------------------------------------------------------
#: Wall seconds of the notebooks that take more than a minute under the suite, measured on a clean
#: clone on the 2-core test machine at light load (2026-12-02; 07 and 08 share their paper runs and
#: run as one unit on one worker; 15, 16 and 17 estimated on 2026-12-07, 16 again on 2026-12-08, from
#: their runs under pytest alone at their shorter test runs). Used only to order the run; any other
#: notebook counts as 20 s.
NOTEBOOK_SECONDS = {"09_moving-drone-and-motion-blur.ipynb": 300, "10_lens-sweep-and-fisheye.ipynb": 255,
                    "16_should-i-buy-a-gimbal.ipynb": 195, "17_the-moving-drone-picks-its-exposure.ipynb": 170,
                    "15_when-does-a-gimbal-pay-off.ipynb": 160, "11_occlusion-and-tracking-filters.ipynb": 80,
                    ("07_active-vs-passive-sphere.ipynb", "08_active-vs-passive-aruco.ipynb"): 255}


def _worker_chunks(items: list, workers: int) -> list:
    """``items`` reordered for pytest-xdist's work-stealing scheduler, which hands the first
    ``len // workers`` items to its first worker, the next share to the second, and so on, and
    lets an idle worker steal from the *end* of another's queue. The notebooks are dealt longest
    first to the worker with the least expected time and lead its share; the unit tests fill the
    shares, so what is stolen at the end is short. Without this the notebooks all sat at the front
    of the first worker's share, and the last long one ran alone (about 1 minute of 17)."""
    notebooks = [item for item in items if _is_notebook(item)]
    tests = [item for item in items if not _is_notebook(item)]
    names = {Path(str(item.path)).name: item for item in notebooks}
    units = []  # (seconds, [items]) in the order given, pairs kept together
    for key, seconds in NOTEBOOK_SECONDS.items():
        group = [names.pop(n) for n in ((key,) if isinstance(key, str) else key) if n in names]
        if group:
            units.append((seconds, group))
    units += [(20, [item]) for item in names.values()]
    units.sort(key=lambda unit: -unit[0])  # stable: the measured order among equals
    shares = [[] for _ in range(workers)]
    expected = [0.0] * workers
    for seconds, group in units:
        k = expected.index(min(expected))
        shares[k] += group
        expected[k] += seconds
    # each share's size as the scheduler cuts it: the remaining items divided by the remaining workers
    total, sizes = len(items), []
    for k in range(workers):
        sizes.append((total - sum(sizes)) // (workers - k))
    ordered = []
    for k, share in enumerate(shares):
        room = max(0, sizes[k] - len(share))
        ordered += share + tests[:room]
        tests = tests[room:]
    return ordered + tests


def pytest_collection_modifyitems(session, config, items):
    worker = getattr(config, "workerinput", None)
    workers = int(worker["workercount"]) if worker is not None else 1
    if workers > 1:  # every worker collects and must order alike: the order depends only on the items
        items[:] = _worker_chunks(list(items), workers)


def pytest_runtest_setup(item):
    # the kernel nbmake starts for a notebook inherits it, and so does a command a test starts
    os.environ[STORE_ENV] = str(Path(os.environ[TEST_STORE_ENV]).expanduser().absolute())
    if _is_notebook(item) and not _user_replicates:
        os.environ["GIMBAL_LAB_REPLICATES"] = _SUITE_REPLICATES


def pytest_runtest_teardown(item):
    os.environ.pop(STORE_ENV, None)


# ----------------------------------------------------------------------------------------------
# time budget
# ----------------------------------------------------------------------------------------------
def _cpu_s() -> float:
    """CPU time (user + system) of this process and of its children that have ended, s: a
    notebook's kernel and the study workers it started count once the notebook is done."""
    own, children = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item, nextitem):
    item._cpu_mark = _cpu_s()
    yield


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    report = (yield).get_result()
    now = _cpu_s()
    # travels with the report to xdist's controlling process
    report.user_properties.append(("cpu_s", now - getattr(item, "_cpu_mark", now)))
    item._cpu_mark = now


def pytest_runtest_logreport(report):
    # the controlling process receives every worker's reports too
    name = report.nodeid.split("::", 1)[0]
    _seconds[name] += report.duration
    _cpu_seconds[name] += sum(value for key, value in report.user_properties if key == "cpu_s")


def load_budget(path: Path = BUDGET_FILE) -> tuple[float | None, dict[str, float]]:
    """The suite's total budget and the budget of each pattern (a glob over test files and
    notebooks, relative to the repository's root, whose times add up), in seconds."""
    if not path.is_file():
        return None, {}
    data = tomllib.loads(path.read_text())
    return data.get("total_s"), dict(data.get("files", {}))


def budget_rows(seconds: dict[str, float], cpu_seconds: dict[str, float], budget: dict[str, float]
                ) -> list[tuple[str, float, float, float | None]]:
    """(pattern or file, seconds, CPU seconds, budget or None) for every budget pattern that
    matches a file (its files' times added up), then for every file no pattern covers, slowest
    first within each part."""
    rows, covered = [], set()
    for pattern, limit in budget.items():
        matched = [name for name in seconds if fnmatch.fnmatchcase(name, pattern)]
        covered.update(matched)
        if matched:
            rows.append((pattern, sum(seconds[n] for n in matched), sum(cpu_seconds.get(n, 0.0) for n in matched),
                         float(limit)))
    rows.sort(key=lambda row: -row[1])
    rest = sorted(((name, s, cpu_seconds.get(name, 0.0), None) for name, s in seconds.items() if name not in covered),
                  key=lambda row: -row[1])
    return rows + rest


def pytest_terminal_summary(terminalreporter, exitstatus, config):
    if getattr(config, "workerinput", None) is not None or not _seconds or "wall" not in _started:
        return
    try:
        total_budget, budget = load_budget()
    except (OSError, tomllib.TOMLDecodeError) as exc:
        terminalreporter.write_line(f"time budget: cannot read {BUDGET_FILE}: {exc}")
        return
    wall = time.time() - _started["wall"]
    everything = config.getoption("--time-budget")
    if not everything and (not total_budget or wall <= total_budget):
        return  # within the total: nothing to say
    rows = budget_rows(_seconds, _cpu_seconds, budget)
    over = [row for row in rows if row[3] is not None and row[1] > row[3]]
    tr = terminalreporter
    tr.section("time budget (benchmarks/suite_budget.toml: wall seconds on a loaded 2-core machine)")
    limit_text = f" (budget {total_budget:.0f} s)" if total_budget else ""
    tr.write_line(f"wall time {wall:.0f} s{limit_text}; the tests' wall times add up to {sum(_seconds.values()):.0f} s, "
                  f"their CPU times to {sum(_cpu_seconds.values()):.0f} s; 1-minute load average "
                  f"{_started['load']:.1f} at the start, {os.getloadavg()[0]:.1f} at the end, {os.cpu_count()} CPUs")
    if everything or over:
        tr.write_line(f"{'wall s':>8s} {'CPU s':>7s} {'budget':>6s}  file or pattern")
    for name, seconds, cpu, limit in rows if everything else over:
        limit_text = "" if limit is None else f"{limit:.0f}"
        mark = "  OVER" if limit is not None and seconds > limit else ""
        tr.write_line(f"{seconds:8.1f} {cpu:7.1f} {limit_text:>6s}  {name}{mark}")
    if over and not everything:
        tr.write_line(f"{len(over)} over their share of the total (every file over by about the same fraction: a slow "
                      "machine; one far further over: it grew); --time-budget lists every file")
