"""Running many closed-loop configs: executors, the results store, progress, interruption.

* **Executors.** :func:`run` sends configs to any :class:`concurrent.futures.Executor`: by default
  a local pool of worker processes started with ``spawn`` (a process that created an OpenGL
  context must never fork), or e.g. a Dask cluster's executor
  (``distributed.Client(address).get_executor()``, see :func:`dask_executor`). Every worker keeps
  one scene renderer per camera, lens and target and reuses it across runs, and uses one llvmpipe
  thread (the fastest setting with one process per core).
* **The results store** (:class:`ResultsStore`): one Parquet frame table and one JSON sidecar
  (config, package version, source hash, seed, timings) per run, each written atomically
  (temporary file, then ``os.replace``). An entry is keyed by the config *and* a hash of the
  package's source, so any change to the code recomputes; a corrupt or foreign entry is reported
  with a warning naming the file and recomputed. Nothing is ever unpickled from disk.
* **Interruption.** Finished runs are stored the moment they finish. Ctrl-C cancels what is
  queued, stops the local workers at once and raises :class:`RunInterrupted` saying how many runs
  were kept; running the same command again resumes. Local workers exit by themselves when the
  parent process dies (even by SIGKILL).
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import json
import logging
import os
import signal
import sys
import tempfile
import threading
import time
import warnings
from concurrent.futures import Executor, FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from multiprocessing import get_context
from pathlib import Path

import pandas as pd

from .simulation import TrackingConfig, TrackingResult, make_renderer, renderer_key, simulate

__all__ = ["ResultsStore", "RunInterrupted", "SourceMismatch", "run", "source_hash", "dask_executor", "staged_folder"]

log = logging.getLogger(__name__)

STORE_FORMAT = 1


@functools.lru_cache(maxsize=1)
def source_hash() -> str:
    """SHA-256 (hex, 16 characters) of every ``.py`` file of the installed package, path and bytes."""
    root = Path(__file__).resolve().parent
    digest = hashlib.sha256()
    for path in sorted(root.rglob("*.py")):
        digest.update(path.relative_to(root).as_posix().encode())
        digest.update(b"\0")
        digest.update(path.read_bytes())
        digest.update(b"\0")
    return digest.hexdigest()[:16]


def _atomic_write(path: Path, write) -> None:
    """Write through ``write(tmp_path)`` to a temporary file beside ``path``, then rename it over."""
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.close(fd)
    try:
        write(tmp)
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        raise


class ResultsStore:
    """A folder of finished runs, one Parquet frame table + JSON sidecar per run.

    Parameters
    ----------
    root : path
        Folder of the store (created when missing). Entries live in ``root/runs``.
    read : bool
        False: never answer from disk (recompute everything) but still store what is computed.

    Notes
    -----
    The entry of a config is ``runs/<key>.parquet`` and ``runs/<key>.json`` with
    key = SHA-256 of the config's key (its fields and schema) and :func:`source_hash`. The sidecar is written last, so
    an entry without one is incomplete and simply recomputed.
    """

    def __init__(self, root, read: bool = True):
        self.read = bool(read)
        root = os.fspath(root)
        if not isinstance(root, str) or not root.strip():
            raise ValueError(f"store root must be a non-empty path, got {root!r}")
        self.root = Path(root)
        self.runs = self.root / "runs"
        self.runs.mkdir(parents=True, exist_ok=True)

    def __repr__(self) -> str:
        return f"ResultsStore({str(self.root)!r})"

    @staticmethod
    def key(config: TrackingConfig) -> str:
        text = json.dumps({"config": config.key, "source": source_hash()}, sort_keys=True)
        return hashlib.sha256(text.encode()).hexdigest()[:24]

    def paths(self, config: TrackingConfig) -> tuple[Path, Path]:
        key = self.key(config)
        return self.runs / f"{key}.parquet", self.runs / f"{key}.json"

    def __contains__(self, config: TrackingConfig) -> bool:
        table, sidecar = self.paths(config)
        return table.exists() and sidecar.exists()

    def load(self, config: TrackingConfig) -> TrackingResult | None:
        """The stored result of ``config``, or None (missing, incomplete, corrupt or foreign)."""
        table, sidecar = self.paths(config)
        if not self.read or not sidecar.exists():
            return None
        try:
            meta = json.loads(sidecar.read_text())
            if not isinstance(meta, dict) or meta.get("format") != STORE_FORMAT:
                raise ValueError("not a results-store sidecar of this format")
            if meta.get("source_hash") != source_hash() or meta.get("config") != json.loads(
                json.dumps(config.to_dict())
            ):
                raise ValueError("it describes another config or another package source")
        except Exception as exc:  # an unreadable entry is recomputed, never trusted
            self._warn(sidecar, exc)
            return None
        try:
            frames = pd.read_parquet(table)
            if len(frames) != meta.get("frames"):
                raise ValueError(f"it holds {len(frames)} frames, its sidecar says {meta.get('frames')}")
        except Exception as exc:
            self._warn(table, exc)
            return None
        return TrackingResult(config=config, frames=frames, timing=dict(meta.get("timing", {})))

    @staticmethod
    def _warn(path: Path, exc: Exception) -> None:
        warnings.warn(f"results store: {path} is unreadable ({exc}); the run is recomputed", RuntimeWarning,
                      stacklevel=3)

    def save(self, result: TrackingResult) -> None:
        """Store ``result`` atomically (table first, sidecar last)."""
        from . import __version__

        table, sidecar = self.paths(result.config)
        _atomic_write(table, lambda tmp: result.frames.to_parquet(tmp, index=False))
        meta = {
            "format": STORE_FORMAT,
            "config": result.config.to_dict(),
            "label": result.config.label,
            "seed": result.config.seed,
            "frames": len(result.frames),
            "package_version": __version__,
            "source_hash": source_hash(),
            "timing": result.timing,
            "written": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        }
        _atomic_write(sidecar, lambda tmp: Path(tmp).write_text(json.dumps(meta, indent=1, sort_keys=True)))


class RunInterrupted(KeyboardInterrupt):
    """Ctrl-C stopped :func:`run`; ``kept`` of ``total`` runs are finished (and stored)."""

    def __init__(self, kept: int, total: int, store: ResultsStore | None):
        self.kept, self.total, self.store = kept, total, store
        where = f" in {store.root}" if store is not None else " (no store: they are lost)"
        super().__init__(f"interrupted: {kept} of {total} runs finished and kept{where}")


# ----------------------------------------------------------------------------------------------
# workers
# ----------------------------------------------------------------------------------------------
_RENDERERS: dict = {}
#: Renderers a worker keeps open at once (study grids run the runs of one renderer together).
MAX_RENDERERS = 4
_PREPARED = False


#: glibc's mallopt parameters, and the values a worker restores when ``MALLOC_TRIM_THRESHOLD_`` is
#: set: 32 MiB is the ceiling glibc's own sliding mmap threshold reaches on 64-bit machines.
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3
_MMAP_THRESHOLD_BYTES = 32 << 20
_TRIM_THRESHOLD_BYTES = 64 << 20


def _keep_frames_on_the_heap() -> bool:
    """Undo a fixed malloc trim threshold in this process (glibc only); True if it did.

    Dask's nannies start workers with ``MALLOC_TRIM_THRESHOLD_=65536``. Setting any malloc
    threshold turns off glibc's sliding mmap threshold, so every frame-sized array (a 640 × 480
    RGB frame is 0.9 MB) is mapped, page-faulted in and unmapped again: measured, a run took 1.46×
    as long in a Dask worker as in a local one, detection included, and 1.07× with the
    thresholds here. They are the ones glibc's own would settle at for this workload."""
    if "MALLOC_TRIM_THRESHOLD_" not in os.environ or not sys.platform.startswith("linux"):
        return False
    import ctypes

    try:
        libc = ctypes.CDLL("libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):  # not glibc
        return False
    return bool(mallopt(_M_MMAP_THRESHOLD, _MMAP_THRESHOLD_BYTES)) and bool(
        mallopt(_M_TRIM_THRESHOLD, _TRIM_THRESHOLD_BYTES))


def _prepare_process() -> None:
    """Once per process, before any GL context: headless EGL, one llvmpipe and one OpenCV thread,
    frames allocated on the heap."""
    global _PREPARED
    if _PREPARED:
        return
    _keep_frames_on_the_heap()
    os.environ.setdefault("LP_NUM_THREADS", "1")
    os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
    import faulthandler

    import cv2

    if not faulthandler.is_enabled() and sys.stderr is not None:
        faulthandler.enable()  # a crash in native code prints the Python stack that led to it

    cv2.setNumThreads(1)
    _PREPARED = True


def _renderer_for(config: TrackingConfig):
    """A renderer for ``config``, reused while runs share its :func:`renderer_key`; the least
    recently used one is closed beyond :data:`MAX_RENDERERS` (a fisheye holds six GL contexts)."""
    key = renderer_key(config)
    renderer = _RENDERERS.pop(key, None)
    if renderer is None:
        while len(_RENDERERS) >= MAX_RENDERERS:
            _RENDERERS.pop(next(iter(_RENDERERS))).close()
        renderer = make_renderer(config)
    _RENDERERS[key] = renderer  # most recently used last
    return renderer


class SourceMismatch(RuntimeError):
    """A worker runs other gimbal_lab code than the process that keys and stores its results."""


def _run_one(config: TrackingConfig, source: str | None = None) -> TrackingResult:
    """What a worker does for one config (module-level so any executor can pickle it). ``source``:
    the submitting process's :func:`source_hash`, which the worker's own must equal (a cluster's
    machines with another gimbal-lab would otherwise fill the store with results under a key that
    says they came from this code)."""
    _prepare_process()
    if source is not None and source != source_hash():
        raise SourceMismatch(
            f"a worker (pid {os.getpid()}) runs gimbal_lab source {source_hash()[:12]}, the sweep's is "
            f"{source[:12]}: install the same gimbal-lab on every worker (pip install of the same checkout)")
    return simulate(config, renderer=_renderer_for(config))


def _watch_parent(parent_pid: int) -> None:
    while True:
        time.sleep(0.5)
        if os.getppid() != parent_pid:
            os._exit(1)  # the parent died (even by SIGKILL): leave no orphan behind


def _local_worker_init(parent_pid: int) -> None:
    # Ctrl-C reaches the whole process group: the parent alone decides what happens.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    threading.Thread(target=_watch_parent, args=(parent_pid,), daemon=True).start()
    _prepare_process()


#: Thread counts of numpy's BLAS (and OpenMP) that a local worker starts with. Each worker is one
#: of ``jobs`` processes sharing the cores, and its matrices are small: a second BLAS thread per
#: worker only spins (measured: a moving-drone run took 20.4 s wall and 39 s of CPU with the
#: default two, 16.2 s and 18.5 s with one). They must be in the environment before the worker
#: imports numpy, so they are set in the parent while it spawns workers (not if already set).
CHILD_THREAD_LIMITS = {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}


@contextlib.contextmanager
def _single_threaded_children():
    added = [name for name in CHILD_THREAD_LIMITS if name not in os.environ]
    os.environ.update({name: CHILD_THREAD_LIMITS[name] for name in added})
    try:
        yield
    finally:
        for name in added:
            os.environ.pop(name, None)


def _check_spawnable_main() -> None:
    """Spawned workers re-import the parent's main script by its path; one read from standard input
    (``python -``) or otherwise not on disk cannot be, and every worker would die at start."""
    path = getattr(sys.modules.get("__main__"), "__file__", None)
    if path is not None and not os.path.exists(path):
        raise RuntimeError(f"the local pool's workers must re-import the main script, {path!r}, which is not a file "
                           "(a script piped to `python -`?): save the script to a file and run that, or call "
                           "run(..., jobs=1) to run in this process")


def _local_pool(jobs: int) -> ProcessPoolExecutor:
    _check_spawnable_main()
    return ProcessPoolExecutor(max_workers=jobs, mp_context=get_context("spawn"), initializer=_local_worker_init,
                               initargs=(os.getpid(),))


#: How many times one :func:`run` replaces a local pool whose worker died (a crash in native code,
#: or a worker killed from outside) before it gives up: the unfinished runs go to the new pool.
MAX_POOL_RESTARTS = 2


def _stop_pool(pool: ProcessPoolExecutor) -> None:
    """Cancel queued work and end the local workers now (they may be mid-render)."""
    processes = list(getattr(pool, "_processes", {}).values())
    pool.shutdown(wait=False, cancel_futures=True)
    for p in processes:
        if p.is_alive():
            p.terminate()
    for p in processes:
        p.join(timeout=5)


def dask_executor(address: str):
    """A :class:`concurrent.futures.Executor` running on the Dask cluster at ``address``; its
    ``shutdown`` (or leaving a ``with`` block) also closes the client it opened.

    Needs the ``[dask]`` extra. Workers must not fork after GL (Dask's nannies spawn workers by
    default) and each keeps its own renderers, as local workers do.
    """
    if not isinstance(address, str) or not address.strip():
        raise ValueError(f"scheduler address must be a non-empty string such as tcp://HOST:8786, got {address!r}")
    try:
        from distributed import Client
        from distributed.cfexecutor import ClientExecutor
    except ImportError as exc:
        raise ImportError("a Dask cluster needs the [dask] extra: pip install 'gimbal-lab[dask]'") from exc

    class ClusterExecutor(ClientExecutor):
        def shutdown(self, wait=True, **kwargs):
            try:
                super().shutdown(wait=wait, **kwargs)
            finally:
                self._client.close()

    return ClusterExecutor(Client(address))


# ----------------------------------------------------------------------------------------------
# run
# ----------------------------------------------------------------------------------------------
def run(configs, *, store=None, executor: Executor | None = None, jobs: int | None = None, progress: bool = True,
        desc: str = "runs") -> list[TrackingResult]:
    """Run ``configs`` (reusing stored runs) and return their results in input order.

    Parameters
    ----------
    configs : sequence of TrackingConfig
        Duplicates are run once.
    store : ResultsStore, path or None
        Where finished runs are kept and looked up (None: nothing is stored).
    executor : concurrent.futures.Executor, optional
        Where runs go (e.g. :func:`dask_executor`). Default: a local pool of ``jobs`` spawned
        worker processes, or this process when ``jobs == 1`` (which then holds a GL context and
        must not fork afterwards).
    jobs : int, optional
        Local worker processes, >= 1 (default: the CPU count, at most the number of runs).
    progress : bool
        One bar over all frames to compute, with frames/s and the time left.

    Raises
    ------
    RunInterrupted
        On Ctrl-C, after stopping the workers; every run finished so far is in the store.
    """
    if isinstance(configs, (TrackingConfig, str, bytes)) or not hasattr(configs, "__iter__"):
        raise TypeError(f"configs must be a sequence of TrackingConfig objects, got {type(configs).__name__}")
    configs = list(configs)
    for c in configs:
        if not isinstance(c, TrackingConfig):
            raise TypeError(f"configs must hold TrackingConfig objects, got {type(c).__name__}")
    if executor is not None and not isinstance(executor, Executor):
        raise TypeError(f"executor must be a concurrent.futures.Executor, got {type(executor).__name__}")
    if jobs is None:
        jobs = os.cpu_count() or 1
    if isinstance(jobs, bool) or not isinstance(jobs, int) or jobs < 1:
        raise ValueError(f"jobs must be an integer >= 1, got {jobs!r}")
    if store is not None and not isinstance(store, ResultsStore):
        store = ResultsStore(store)

    unique: dict[TrackingConfig, TrackingResult | None] = dict.fromkeys(configs)
    for c in unique:
        unique[c] = store.load(c) if store is not None else None
    todo = [c for c, r in unique.items() if r is None]
    # Longest runs first keeps every worker busy to the end (ArUco frames cost more).
    todo.sort(key=lambda c: (-c.n_frames, c.target.kind != "aruco"))

    bar = None
    if progress and todo:
        from tqdm.auto import tqdm

        bar = tqdm(total=sum(c.n_frames for c in todo), desc=desc, unit="frame", dynamic_ncols=True)
    done = 0
    saving = None  # the run being stored: Ctrl-C may land after its files are written, before it is counted

    def finish(config, result):
        nonlocal done, saving
        saving = config
        if store is not None:
            store.save(result)
        unique[config] = result  # only now: a run counts as kept once it is stored
        saving = None
        done += 1
        seconds = result.timing.get("total_s", float("nan"))
        log.info("%s seed %d: %d frames in %.1f s", config.label, config.seed, len(result.frames), seconds)
        if bar is not None:
            bar.update(len(result.frames))
            bar.set_postfix_str(f"{done}/{len(todo)} runs")

    pool = None
    futures: dict = {}
    # Workers spawn while this block submits; they inherit its environment (CHILD_THREAD_LIMITS).
    with _single_threaded_children() if executor is None else contextlib.nullcontext():
        try:
            if executor is None and (jobs == 1 or len(todo) <= 1):
                for c in todo:
                    finish(c, _run_one(c))
            elif todo:
                pool = executor if executor is not None else _local_pool(min(jobs, len(todo)))
                futures = {pool.submit(_run_one, c, source_hash()): c for c in todo}
                pending = set(futures)
                restarts = 0
                while pending:
                    finished, pending = wait(pending, return_when=FIRST_COMPLETED)
                    broken = [fut for fut in finished if isinstance(fut.exception(), BrokenProcessPool)]
                    for fut in finished:
                        if fut not in broken:
                            finish(futures[fut], fut.result())
                    if not broken:
                        continue
                    # A local worker died: every queued run of that pool fails with it. The runs are
                    # deterministic, so a new pool computes exactly what the dead one would have.
                    if executor is not None or restarts >= MAX_POOL_RESTARTS:
                        broken[0].result()
                    restarts += 1
                    _stop_pool(pool)
                    unfinished = [c for c in todo if unique[c] is None]
                    warnings.warn(f"a worker process died ({broken[0].exception()}); starting new workers for the "
                                  f"{len(unfinished)} unfinished run(s), {MAX_POOL_RESTARTS - restarts} restart(s) "
                                  "left", RuntimeWarning, stacklevel=2)
                    pool = _local_pool(min(jobs, len(unfinished)))
                    futures = {pool.submit(_run_one, c, source_hash()): c for c in unfinished}
                    pending = set(futures)
        except BaseException as exc:
            # Ctrl-C or a failed run: stop the rest at once instead of computing runs nobody will see
            if pool is not None and executor is None:
                _stop_pool(pool)
                pool = None
            for fut in futures:
                fut.cancel()
            if isinstance(exc, KeyboardInterrupt):
                if saving is not None and unique[saving] is None and store is not None:
                    unique[saving] = store.load(saving)  # stored whole before Ctrl-C landed, or None
                kept = sum(r is not None for r in unique.values())
                raise RunInterrupted(kept, len(unique), store) from None
            raise
        finally:
            if pool is not None and executor is None:
                pool.shutdown(wait=True)
            if bar is not None:
                bar.close()
    return [unique[c] for c in configs]


# ----------------------------------------------------------------------------------------------
# output folders
# ----------------------------------------------------------------------------------------------
class staged_folder:
    """Write a whole output folder, then swap it in: never a mix of old and new files.

    ``with staged_folder(path) as tmp:`` yields an empty sibling folder; on success the old
    ``path`` is moved aside, ``tmp`` renamed to ``path`` and the old one deleted; on any error
    (Ctrl-C included) ``tmp`` is deleted and ``path`` is left as it was. Leftovers of a killed
    process are removed the next time.
    """

    def __init__(self, path):
        path = os.fspath(path)
        if not isinstance(path, str) or not path.strip():
            raise ValueError(f"output folder must be a non-empty path, got {path!r}")
        self.path = Path(path)
        self.staging = self.path.parent / f".{self.path.name}.staging-{os.getpid()}"
        self.old = self.path.parent / f".{self.path.name}.old-{os.getpid()}"

    def __enter__(self) -> Path:
        import shutil

        self.path.parent.mkdir(parents=True, exist_ok=True)
        for leftover in self.path.parent.glob(f".{self.path.name}.*-*"):
            pid = leftover.name.rsplit("-", 1)[-1]
            if pid.isdigit() and not _alive(int(pid)):
                shutil.rmtree(leftover, ignore_errors=True)
        shutil.rmtree(self.staging, ignore_errors=True)
        self.staging.mkdir()
        return self.staging

    def __exit__(self, exc_type, exc, tb) -> None:
        import shutil

        if exc_type is not None:
            shutil.rmtree(self.staging, ignore_errors=True)
            return
        if self.path.exists():
            os.rename(self.path, self.old)
        os.rename(self.staging, self.path)
        shutil.rmtree(self.old, ignore_errors=True)


def _alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


if sys.platform == "win32":  # pragma: no cover - the lab targets Linux servers
    warnings.warn("gimbal_lab.runner is tested on Linux only", RuntimeWarning)
