"""The runner: the results store (round trip, reuse, corrupt entries, source-hash keying), local
and Dask executors giving the same frames as one process, Ctrl-C and SIGKILL of a running sweep
(no orphan workers, resume), staged output folders, and bad inputs.

Every run here is tiny (160 × 120 px, a few frames to a few revolutions) so the file stays fast
on two cores; the subprocess tests run real spawned worker pools.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import re
import shutil
import signal
import subprocess
import sys
import textwrap
import time
import warnings
from pathlib import Path
from typing import NamedTuple

import pandas as pd
import pytest
from pandas.testing import assert_frame_equal

from gimbal_lab import runner
from gimbal_lab.config import Pointing
from gimbal_lab.runner import ResultsStore, RunInterrupted, dask_executor, run, source_hash, staged_folder
from gimbal_lab.simulation import TrackingConfig


def cfg(**changes) -> TrackingConfig:
    """A cheap config: small images and 0.1 revolution (6 frames) unless told otherwise (``changes``
    as :meth:`TrackingConfig.with_` takes them, ``part__field=value``)."""
    return TrackingConfig().with_(**{"revolutions": 0.1, "camera__width": 160, "camera__height": 120, **changes})


#: A few different configs (targets, modes, lenses) for the executor comparisons.
CONFIGS = [
    cfg(seed=0),
    cfg(pointing__kind="paper", camera__lens="default", seed=1),
    cfg(target__kind="aruco", target__trajectory="diagonal", revolutions=0.15, seed=2),
]


def count_runs(monkeypatch) -> list:
    """Record every config computed in this process (jobs=1 or a single run) by the runner."""
    calls = []
    original = runner._run_one

    def counting(config, source=None):
        calls.append(config)
        return original(config, source)

    monkeypatch.setattr(runner, "_run_one", counting)
    return calls


def assert_same_results(got, expected):
    assert len(got) == len(expected)
    for g, e in zip(got, expected):
        assert g.config == e.config
        assert_frame_equal(g.frames, e.frames, check_exact=True)  # bit-equal, not merely close


@pytest.fixture(scope="module")
def reference():
    """CONFIGS run in this process (jobs=1), with the wall time."""
    t0 = time.perf_counter()
    results = run(CONFIGS, jobs=1, progress=False)
    seconds = time.perf_counter() - t0
    print(f"\n[wall time] jobs=1, {len(CONFIGS)} configs in this process: {seconds:.2f} s")
    return results


# ------------------------------------------------------------------------------------------------
# the results store
# ------------------------------------------------------------------------------------------------
def test_store_round_trip_and_reuse(tmp_path, monkeypatch):
    c = cfg(seed=5)
    [first] = run([c], store=tmp_path / "store", jobs=1, progress=False)
    store = ResultsStore(tmp_path / "store")
    table, sidecar = store.paths(c)
    assert table.parent == tmp_path / "store" / "runs"
    assert table.exists() and sidecar.exists() and c in store
    assert len(first.frames) == c.n_frames == 6

    loaded = store.load(c)
    assert loaded is not None and loaded.config == c
    assert_frame_equal(loaded.frames, first.frames, check_exact=True)
    meta = json.loads(sidecar.read_text())
    assert meta["config"] == c.to_dict() and meta["source_hash"] == source_hash()
    assert meta["frames"] == 6 and meta["seed"] == 5 and meta["timing"] == first.timing
    assert not list(store.runs.glob("*.tmp")) and not list(store.runs.glob(".*"))  # no temporary left

    # A second run answers from the store: nothing is computed and nothing is rewritten.
    mtimes = (table.stat().st_mtime_ns, sidecar.stat().st_mtime_ns)

    def must_not_run(config):
        raise AssertionError(f"recomputed {config.label} although it is stored")

    monkeypatch.setattr(runner, "_run_one", must_not_run)
    monkeypatch.setattr(runner, "simulate", must_not_run)
    [again] = run([c], store=store, jobs=1, progress=True)
    assert_frame_equal(again.frames, first.frames, check_exact=True)
    assert again.timing == first.timing
    assert (table.stat().st_mtime_ns, sidecar.stat().st_mtime_ns) == mtimes


def test_store_without_read_recomputes_but_writes(tmp_path, monkeypatch):
    c = cfg(seed=6)
    [first] = run([c], store=tmp_path / "s", jobs=1, progress=False)
    sidecar = ResultsStore(tmp_path / "s").paths(c)[1]
    written = json.loads(sidecar.read_text())["written"]
    os.utime(sidecar, ns=(0, 0))  # so that a rewrite is visible whatever the clock's resolution
    calls = count_runs(monkeypatch)
    no_read = ResultsStore(tmp_path / "s", read=False)
    assert no_read.load(c) is None
    [again] = run([c], store=no_read, jobs=1, progress=False)
    assert calls == [c]
    assert sidecar.stat().st_mtime_ns > 0 and json.loads(sidecar.read_text())["written"] >= written
    assert_frame_equal(again.frames, first.frames, check_exact=True)


def test_duplicates_run_once_and_results_keep_input_order(monkeypatch):
    a, b = cfg(seed=7), cfg(seed=8, revolutions=0.2)  # b is longer: the runner starts it first
    calls = count_runs(monkeypatch)
    results = run([a, b, a], jobs=1, progress=False)
    assert sorted(calls, key=lambda c: c.seed) == [a, b]
    assert [r.config for r in results] == [a, b, a]
    assert results[0] is results[2]
    assert len(results[1].frames) == 12 and not results[0].frames.equals(results[1].frames)


def _corrupt(kind: str, store: ResultsStore, c: TrackingConfig, other: TrackingConfig) -> Path:
    """Damage the stored entry of ``c``; return the file the warning must name."""
    table, sidecar = store.paths(c)
    if kind == "garbage sidecar":
        sidecar.write_text("{ this is not JSON")
        return sidecar
    if kind == "sidecar of another format":
        sidecar.write_text(json.dumps([1, 2, 3]))
        return sidecar
    if kind == "sidecar of another config":
        other_table, other_sidecar = store.paths(other)
        shutil.copyfile(other_sidecar, sidecar)
        shutil.copyfile(other_table, table)
        return sidecar
    if kind == "sidecar of the flat config":  # written before the config had parts: its fields in one table
        meta = json.loads(sidecar.read_text())
        meta["config"] = {k: v for part in meta["config"].values() if isinstance(part, dict) for k, v in part.items()}
        meta["config"].update(revolutions=c.revolutions, seed=c.seed, mode="passive", distortion="none")
        sidecar.write_text(json.dumps(meta))
        return sidecar
    if kind == "truncated parquet":
        data = table.read_bytes()
        table.write_bytes(data[: len(data) // 2])
        return table
    if kind == "empty parquet":
        table.write_bytes(b"")
        return table
    if kind == "parquet with fewer frames":
        pd.read_parquet(table).iloc[:3].to_parquet(table, index=False)
        return table
    if kind == "parquet missing":
        table.unlink()
        return table
    raise AssertionError(kind)


@pytest.mark.parametrize("kind", ["garbage sidecar", "sidecar of another format", "sidecar of another config",
                                  "sidecar of the flat config", "truncated parquet", "empty parquet", "parquet with fewer frames",
                                  "parquet missing"])
def test_corrupt_entry_warns_naming_the_file_and_is_recomputed(tmp_path, monkeypatch, kind):
    c, other = cfg(seed=9), cfg(seed=10)
    store = ResultsStore(tmp_path / "store")
    clean = run([c, other], store=store, jobs=1, progress=False)
    bad = _corrupt(kind, store, c, other)

    with pytest.warns(RuntimeWarning, match=re.escape(str(bad))):
        assert store.load(c) is None
    calls = count_runs(monkeypatch)
    with pytest.warns(RuntimeWarning, match=re.escape(str(bad))):
        [again] = run([c], store=store, jobs=1, progress=False)
    assert calls == [c]  # recomputed, not served
    assert_frame_equal(again.frames, clean[0].frames, check_exact=True)

    # the recomputed run repaired the entry: it now loads silently, and the other entry is intact
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert_frame_equal(store.load(c).frames, clean[0].frames, check_exact=True)
        assert_frame_equal(store.load(other).frames, clean[1].frames, check_exact=True)


def test_incomplete_entry_without_sidecar_is_recomputed_silently(tmp_path, monkeypatch):
    c = cfg(seed=11)
    store = ResultsStore(tmp_path / "store")
    [clean] = run([c], store=store, jobs=1, progress=False)
    store.paths(c)[1].unlink()  # e.g. killed between the table and the sidecar
    assert c not in store
    calls = count_runs(monkeypatch)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        [again] = run([c], store=store, jobs=1, progress=False)
    assert calls == [c]
    assert_frame_equal(again.frames, clean.frames, check_exact=True)


def test_store_is_keyed_by_the_source_hash(tmp_path, monkeypatch):
    c = cfg(seed=12)
    store = ResultsStore(tmp_path / "store")
    [clean] = run([c], store=store, jobs=1, progress=False)
    old_table, old_sidecar = store.paths(c)
    old_mtime = old_sidecar.stat().st_mtime_ns

    # Another package source: the entry written under the current one must not be served.
    other_source = "0123456789abcdef"
    assert other_source != source_hash()
    monkeypatch.setattr(runner, "source_hash", lambda: other_source)
    new_table, new_sidecar = store.paths(c)
    assert new_sidecar != old_sidecar
    assert c not in store and store.load(c) is None
    calls = count_runs(monkeypatch)
    [again] = run([c], store=store, jobs=1, progress=False)
    assert calls == [c]
    assert_frame_equal(again.frames, clean.frames, check_exact=True)
    assert json.loads(new_sidecar.read_text())["source_hash"] == other_source
    assert old_sidecar.stat().st_mtime_ns == old_mtime  # the other source's entry is left alone

    # An entry of the other source placed under this source's name is foreign: warned and ignored.
    shutil.copyfile(old_sidecar, new_sidecar)
    shutil.copyfile(old_table, new_table)
    with pytest.warns(RuntimeWarning, match=re.escape(str(new_sidecar))):
        assert store.load(c) is None


# ------------------------------------------------------------------------------------------------
# executors
# ------------------------------------------------------------------------------------------------
def test_local_pool_gives_the_same_frames_as_one_process(reference):
    configs = CONFIGS + [CONFIGS[0]]  # a duplicate is run once and returned twice
    t0 = time.perf_counter()
    results = run(configs, jobs=2, progress=True)
    seconds = time.perf_counter() - t0
    print(f"\n[wall time] jobs=2, {len(CONFIGS)} configs on a spawned local pool: {seconds:.2f} s")
    assert_same_results(results, reference + [reference[0]])
    assert results[0] is results[3]


def _environment(names):
    return {name: os.environ.get(name) for name in names}


def test_local_workers_start_with_one_blas_thread(monkeypatch):
    """Workers spawned inside the runner's pool block inherit one BLAS/OpenMP thread; a limit the
    user set is kept, and the parent's environment is left as it was."""
    import multiprocessing

    from gimbal_lab.runner import CHILD_THREAD_LIMITS, _single_threaded_children

    names = sorted(CHILD_THREAD_LIMITS)
    for name in names:
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setenv("OMP_NUM_THREADS", "3")
    before = _environment(names)
    with _single_threaded_children():
        with multiprocessing.get_context("spawn").Pool(1) as pool:
            child = pool.apply(_environment, (names,))
    assert child == {"MKL_NUM_THREADS": "1", "OMP_NUM_THREADS": "3", "OPENBLAS_NUM_THREADS": "1"}
    assert _environment(names) == before


_MMAPPED_FRAMES = """
import ctypes, os, sys
import numpy as np
from gimbal_lab.runner import _keep_frames_on_the_heap, _prepare_process

class MallInfo2(ctypes.Structure):
    _fields_ = [(n, ctypes.c_size_t) for n in
                ("arena", "ordblks", "smblks", "hblks", "hblkhd", "usmblks", "fsmblks", "uordblks", "fordblks", "keepcost")]

libc = ctypes.CDLL("libc.so.6")
libc.mallinfo2.restype = MallInfo2

def mapped_frames():
    before = libc.mallinfo2().hblks
    frames = [np.empty((480, 640, 3), np.uint8) for _ in range(4)]
    return libc.mallinfo2().hblks - before

first = mapped_frames()
_prepare_process()  # what a worker does before its first run
after = mapped_frames()
print(first, _keep_frames_on_the_heap(), after)
"""


# The oracle is glibc's allocator statistics, and the fix is glibc's mallopt: Linux only (the
# package, like its runner, targets Linux servers); mallinfo2 exists from glibc 2.33 on, so an older
# glibc or another C library skips with that reason instead of failing on a missing symbol.
@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's malloc statistics: Linux only")
@pytest.mark.parametrize("trim", ["65536", None], ids=["dask-worker", "plain"])
def test_workers_keep_frames_on_the_heap_when_malloc_trim_is_fixed(trim):
    """Oracle: glibc's own count of memory-mapped blocks (``mallinfo2().hblks``). With
    ``MALLOC_TRIM_THRESHOLD_`` set, as Dask's nannies start workers, each 0.9 MB frame is its own
    mapping; after the worker's preparation none is. Without it glibc's sliding threshold is left
    alone (here the frames' first allocation is mapped and the threshold then rises past them)."""
    env = {k: v for k, v in os.environ.items() if k != "MALLOC_TRIM_THRESHOLD_"}
    if trim is not None:
        env["MALLOC_TRIM_THRESHOLD_"] = trim
    probe = subprocess.run([sys.executable, "-c", _MMAPPED_FRAMES], env=env, capture_output=True, text=True,
                           timeout=120)
    if "mallinfo2" in probe.stderr:
        pytest.skip("this C library has no mallinfo2 (glibc >= 2.33 has): the oracle is unavailable")
    assert probe.returncode == 0, probe.stderr
    first, changed, after = probe.stdout.split()
    if trim is not None:
        assert (first, changed, after) == ("4", "True", "0")
    else:
        assert changed == "False"


def test_dask_executor_gives_the_same_frames_as_one_process(reference):
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0",
                                  silence_logs=logging.ERROR) as cluster:
        with dask_executor(cluster.scheduler_address) as executor:
            t0 = time.perf_counter()
            results = run(CONFIGS, executor=executor, progress=False)
            seconds = time.perf_counter() - t0
        assert executor._client.status == "closed"  # leaving the block closed the client it opened
    print(f"\n[wall time] Dask LocalCluster (2 worker processes), {len(CONFIGS)} configs: {seconds:.2f} s")
    assert_same_results(results, reference)


# ------------------------------------------------------------------------------------------------
# Ctrl-C and SIGKILL of a sweep running on local workers (real subprocesses)
# ------------------------------------------------------------------------------------------------
# The sweep tests find the pool's workers and their states through /proc (Linux only); elsewhere
# they cannot tell a live worker from a zombie and are skipped.
needs_proc = pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs Linux /proc")

SWEEP_SCRIPT = textwrap.dedent('''
    import json, multiprocessing, os, signal, sys, time

    from gimbal_lab.runner import ResultsStore, RunInterrupted, run, source_hash
    from gimbal_lab.simulation import TrackingConfig


    def alive_workers():
        """Pool workers still running (a dead one may briefly look alive to multiprocessing)."""
        alive = []
        for child in multiprocessing.active_children():
            try:
                with open(f"/proc/{child.pid}/stat") as f:
                    state = f.read().rsplit(")", 1)[1].split()[0]
            except OSError:
                continue
            if state not in ("Z", "X"):
                alive.append(child.pid)
        return alive


    def main():
        store_root, configs_path = sys.argv[1], sys.argv[2]
        configs = [TrackingConfig.from_dict(d) for d in json.loads(open(configs_path).read())]
        saved = []
        original_save = ResultsStore.save

        def save(self, result):
            original_save(self, result)
            saved.append(result.config.key)

        ResultsStore.save = save
        sigint_at = []

        def on_sigint(signum, frame):  # Python's own behaviour, plus the time
            sigint_at.append(time.monotonic())
            raise KeyboardInterrupt

        signal.signal(signal.SIGINT, on_sigint)
        report = {"pid": os.getpid(), "source_hash": source_hash()}
        try:
            run(configs, store=store_root, jobs=2, progress=False)
        except RunInterrupted as exc:
            report.update(event="interrupted", kept=exc.kept, total=exc.total, saved=len(saved),
                          alive_workers=alive_workers(), stop_s=time.monotonic() - sigint_at[0])
            print(json.dumps(report), flush=True)
            sys.exit(130)
        report.update(event="done", saved=len(saved))
        print(json.dumps(report), flush=True)


    if __name__ == "__main__":
        main()
''')


class Proc(NamedTuple):
    pid: int
    start: int  # start time in clock ticks: tells a process from a later one with the same pid


def _stat(pid: int):
    """(state, ppid, start time) of ``pid``, or None once it is gone."""
    try:
        text = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    fields = text[text.rindex(")") + 2:].split()
    return fields[0], int(fields[1]), int(fields[19])


def _descendants(pid: int) -> dict[Proc, tuple[int, str]]:
    """Every process below ``pid``, with its parent's pid and its command line."""
    children: dict[int, list[tuple[int, int]]] = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            st = _stat(int(entry.name))
            if st is not None:
                children.setdefault(st[1], []).append((int(entry.name), st[2]))
    found, stack = {}, [pid]
    while stack:
        parent = stack.pop()
        for child, start in children.get(parent, []):
            try:
                cmdline = Path(f"/proc/{child}/cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
            except OSError:
                continue
            found[Proc(child, start)] = (parent, cmdline)
            stack.append(child)
    return found


def _alive(p: Proc) -> bool:
    st = _stat(p.pid)
    return st is not None and st[2] == p.start and st[0] not in ("Z", "X")  # a zombie has exited


def _workers(procs: dict[Proc, tuple[int, str]], parent: int) -> list[Proc]:
    """The pool workers spawned by ``parent`` (not its resource tracker, nor what workers start)."""
    return [p for p, (ppid, cmdline) in procs.items() if ppid == parent and "spawn_main" in cmdline]


def _wait_dead(procs, timeout: float) -> list[Proc]:
    deadline = time.monotonic() + timeout
    while True:
        alive = [p for p in procs if _alive(p)]
        if not alive or time.monotonic() > deadline:
            return alive
        time.sleep(0.05)


def _kill_leftovers(procs) -> None:
    for p in procs:
        if _alive(p):
            os.kill(p.pid, signal.SIGKILL)


def _start_sweep(tmp_path: Path, configs) -> tuple[subprocess.Popen, Path, list]:
    script = tmp_path / "sweep.py"
    script.write_text(SWEEP_SCRIPT)
    configs_path = tmp_path / "configs.json"
    configs_path.write_text(json.dumps([c.to_dict() for c in configs]))
    store = tmp_path / "store"
    args = [sys.executable, str(script), str(store), str(configs_path)]
    env = {**os.environ, "PYOPENGL_PLATFORM": "egl", "LP_NUM_THREADS": "1"}
    # A session of its own: Ctrl-C is sent to its whole process group, as a terminal does. Output
    # goes to files, not pipes: the workers inherit them and would hold a pipe open.
    with open(tmp_path / "stdout.txt", "w") as out, open(tmp_path / "stderr.txt", "w") as err:
        proc = subprocess.Popen(args, stdout=out, stderr=err, env=env, start_new_session=True)
    return proc, store / "runs", args


@contextlib.contextmanager
def _sweep(tmp_path: Path, configs):
    """A running sweep (process, store runs folder, command, processes seen so far); on leaving,
    whatever happened, the sweep's process group and every process it started are killed."""
    proc, runs, args = _start_sweep(tmp_path, configs)
    seen: dict[Proc, tuple[int, str]] = {}
    try:
        yield proc, runs, args, seen
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
        _kill_leftovers(seen)


def _output(tmp_path: Path) -> tuple[str, str]:
    return (tmp_path / "stdout.txt").read_text(), (tmp_path / "stderr.txt").read_text()


def _wait_first_result(proc: subprocess.Popen, runs: Path, seen: dict, timeout: float = 120.0) -> None:
    """Poll the store until a sidecar lands, collecting the sweep's processes meanwhile."""
    deadline = time.monotonic() + timeout
    while not (runs.is_dir() and any(runs.glob("*.json"))):
        seen |= _descendants(proc.pid)
        if proc.poll() is not None:
            out, err = _output(runs.parent.parent)
            pytest.fail(f"the sweep ended (code {proc.returncode}) before any result landed:\n{out}\n{err}")
        if time.monotonic() > deadline:
            pytest.fail("no result landed in the store in time")
        time.sleep(0.02)
    seen |= _descendants(proc.pid)


def _last_report(out: str) -> dict:
    lines = [line for line in out.splitlines() if line.startswith("{")]
    assert lines, f"the sweep printed no report: {out!r}"
    return json.loads(lines[-1])


def _stored_frames(runs: Path, source: str) -> dict[str, pd.DataFrame]:
    """Frames of every entry in ``runs`` written under the package source ``source``, by config key."""
    found = {}
    for sidecar in runs.glob("*.json"):
        meta = json.loads(sidecar.read_text())
        if meta["source_hash"] == source:
            key = TrackingConfig.from_dict(meta["config"]).key
            assert key not in found
            found[key] = pd.read_parquet(sidecar.with_suffix(".parquet"))
    return found


@needs_proc
def test_ctrl_c_stops_workers_keeps_finished_runs_and_resumes(tmp_path):
    # Different lengths (longest is started first): one result lands while the others still run.
    # Worker 1 runs the 10-revolution config (~2.5 s), worker 2 the 2-revolution one and then idles:
    # when the first result lands, worker 1 still has ~2 s to go.
    configs = [cfg(revolutions=10, seed=30), cfg(revolutions=2, pointing__kind="paper", seed=31)]
    with _sweep(tmp_path, configs) as (proc, runs, args, seen):
        _wait_first_result(proc, runs, seen)
        assert len(_workers(seen, proc.pid)) == 2, seen
        os.killpg(proc.pid, signal.SIGINT)
        t0 = time.monotonic()
        proc.wait(timeout=20)
        stop_s = time.monotonic() - t0
        # the parent itself stopped its workers before exiting (their watchdog would only do it later)
        workers_left = [p for p in _workers(seen, proc.pid) if _alive(p)]
        left = _wait_dead(seen, timeout=5.0)
    print(f"\n[wall time] Ctrl-C to exit: {stop_s:.2f} s")
    out, err = _output(tmp_path)
    assert not workers_left, f"workers alive after the parent exited: {workers_left}"
    assert not left, f"a process of the sweep outlived it: {left}"
    assert proc.returncode == 130, f"exit code {proc.returncode}\n{err}"
    report = _last_report(out)
    assert report["event"] == "interrupted" and report["alive_workers"] == [], report
    # stopped at once (measured 0.03 s), not after the running configs finished
    assert report["stop_s"] < 1.0, report
    # the workers ignore Ctrl-C (the parent alone handles it): no worker reports one on stderr
    assert not re.search(r"Traceback|KeyboardInterrupt|^Process \w*Process-\d+:", err, re.M), err
    assert report["total"] == 2 and report["kept"] == 1, report
    sidecars = sorted(runs.glob("*.json"))
    # the run said to be kept is in the store, complete, even when Ctrl-C lands while it is being
    # stored (the sweep script's own count of saves can then miss the last one: at most one short)
    assert report["kept"] == len(sidecars), (report, sidecars)
    assert report["kept"] - 1 <= report["saved"] <= report["kept"], report
    assert not [p for p in runs.iterdir() if p.name.endswith(".tmp")]

    # The same command again resumes: only the missing runs are computed.
    done = subprocess.run(args, capture_output=True, text=True, timeout=180,
                          env={**os.environ, "PYOPENGL_PLATFORM": "egl", "LP_NUM_THREADS": "1"})
    assert done.returncode == 0, done.stderr
    resumed = _last_report(done.stdout)
    assert resumed["event"] == "done"
    if resumed["source_hash"] == report["source_hash"]:  # (the package's files may be edited meanwhile)
        assert resumed["saved"] == 1

    stored = _stored_frames(runs, resumed["source_hash"])
    clean = run(configs, jobs=1, progress=False)
    assert sorted(stored) == sorted(c.key for c in configs)
    for result in clean:
        assert_frame_equal(stored[result.config.key], result.frames, check_exact=True)


@needs_proc
def test_a_worker_killed_mid_sweep_is_replaced_and_every_run_lands_unchanged(tmp_path):
    """A worker that dies (a crash in native code, the out-of-memory killer; here SIGKILL) breaks
    the local pool; the sweep starts new workers for the unfinished runs, says so, and ends with
    every run stored, each bit-equal to a clean run."""
    configs = [cfg(revolutions=10, seed=60), cfg(revolutions=2, seed=61), cfg(revolutions=2, pointing__kind="paper", seed=62)]
    with _sweep(tmp_path, configs) as (proc, runs, _, seen):
        _wait_first_result(proc, runs, seen)
        workers = [p for p in _workers(seen, proc.pid) if _alive(p)]
        assert workers, seen
        os.kill(workers[0].pid, signal.SIGKILL)
        proc.wait(timeout=180)
        seen |= _descendants(proc.pid)
    out, err = _output(tmp_path)
    assert proc.returncode == 0, err
    assert "a worker process died" in err and "starting new workers" in err, err
    report = _last_report(out)
    assert report["event"] == "done", report
    stored = _stored_frames(runs, report["source_hash"])
    assert sorted(stored) == sorted(c.key for c in configs)
    for result in run(configs, jobs=1, progress=False):
        assert_frame_equal(stored[result.config.key], result.frames, check_exact=True)


@needs_proc
def test_workers_ignore_sigint_and_sigkill_of_the_parent_leaves_no_orphans(tmp_path):
    # One long run keeps a worker busy; the other worker finishes its short run and idles.
    configs = [cfg(revolutions=60, seed=40), cfg(seed=41)]
    with _sweep(tmp_path, configs) as (proc, runs, _, seen):
        _wait_first_result(proc, runs, seen)
        workers = _workers(seen, proc.pid)
        assert len(workers) == 2, seen
        # Ctrl-C reaching the workers alone (one busy, one idle) is ignored: the sweep carries on.
        for w in workers:
            os.kill(w.pid, signal.SIGINT)
        time.sleep(0.5)
        assert proc.poll() is None, _output(tmp_path)
        assert all(_alive(w) for w in workers), _output(tmp_path)
        os.kill(proc.pid, signal.SIGKILL)  # the parent alone, as the OOM killer would
        proc.wait(timeout=10)
        left = _wait_dead(seen, timeout=5.0)
    assert proc.returncode == -signal.SIGKILL
    assert not left, f"orphans 5 s after the parent was killed: {left}"


# ------------------------------------------------------------------------------------------------
# staged output folders
# ------------------------------------------------------------------------------------------------
def _tree(path: Path) -> dict[str, str]:
    return {p.relative_to(path).as_posix(): p.read_text() for p in sorted(path.rglob("*")) if p.is_file()}


def test_staged_folder_swaps_in_the_new_folder_on_success(tmp_path):
    out = tmp_path / "report"
    (out / "sub").mkdir(parents=True)
    (out / "old.txt").write_text("old")
    (out / "sub" / "old2.txt").write_text("old2")
    with staged_folder(out) as tmp:
        assert tmp.is_dir() and tmp != out and tmp.parent == out.parent and not any(tmp.iterdir())
        (tmp / "new.txt").write_text("new")
        assert _tree(out) == {"old.txt": "old", "sub/old2.txt": "old2"}  # not yet visible
    assert _tree(out) == {"new.txt": "new"}  # never a mix of old and new files
    assert sorted(p.name for p in tmp_path.iterdir()) == ["report"]  # staging and old copy removed

    fresh = tmp_path / "deeper" / "fresh"
    with staged_folder(fresh) as tmp:
        (tmp / "a.txt").write_text("a")
    assert _tree(fresh) == {"a.txt": "a"}


@pytest.mark.parametrize("error", [RuntimeError, KeyboardInterrupt])
def test_staged_folder_keeps_the_old_folder_on_error(tmp_path, error):
    out = tmp_path / "report"
    out.mkdir()
    (out / "old.txt").write_text("old")
    with pytest.raises(error):
        with staged_folder(out) as tmp:
            (tmp / "half.txt").write_text("half written")
            raise error("boom")
    assert _tree(out) == {"old.txt": "old"}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["report"]

    missing = tmp_path / "never"
    with pytest.raises(error):
        with staged_folder(missing) as tmp:
            raise error("boom")
    assert not missing.exists()


def test_staged_folder_removes_leftovers_of_dead_processes_only(tmp_path):
    out = tmp_path / "report"
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    dead_left = tmp_path / f".report.staging-{dead.pid}"
    live_left = tmp_path / f".report.staging-{os.getppid()}"  # a live process that is not this one
    for d in (dead_left, live_left):
        d.mkdir()
        (d / "x").write_text("x")
    with staged_folder(out) as tmp:
        (tmp / "a.txt").write_text("a")
    assert not dead_left.exists()
    assert live_left.exists()
    assert _tree(out) == {"a.txt": "a"}


# ------------------------------------------------------------------------------------------------
# bad inputs
# ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("jobs", [0, -1, True, 1.5, "2"])
def test_run_rejects_bad_jobs(jobs, monkeypatch):
    calls = count_runs(monkeypatch)
    with pytest.raises(ValueError, match="jobs must be an integer >= 1"):
        run([cfg()], jobs=jobs, progress=False)
    assert calls == []


@pytest.mark.parametrize("item", [{"target": "sphere"}, None, "sphere", cfg().to_dict()])
def test_run_rejects_items_that_are_not_configs(item):
    with pytest.raises(TypeError, match="configs must hold TrackingConfig objects, got"):
        run([cfg(), item], jobs=1, progress=False)


@pytest.mark.parametrize("configs, name", [("sphere", "str"), (None, "NoneType"), (cfg(), "TrackingConfig")])
def test_run_rejects_configs_that_are_not_a_sequence(configs, name, monkeypatch):
    calls = count_runs(monkeypatch)
    with pytest.raises(TypeError, match=f"configs must be a sequence of TrackingConfig objects, got {name}$"):
        run(configs, jobs=1, progress=False)
    assert calls == []


def test_bad_jobs_leave_no_store_folder_behind(tmp_path):
    with pytest.raises(ValueError, match="jobs must be an integer >= 1"):
        run([cfg()], store=tmp_path / "never", jobs=0, progress=False)
    assert not (tmp_path / "never").exists()


def test_a_failing_run_stops_the_queued_ones(tmp_path, monkeypatch):
    """The first run raises: the error reaches the caller and the runs still queued never start."""
    from concurrent.futures import ThreadPoolExecutor

    started = []

    def failing(config, source=None):
        started.append(config)
        time.sleep(0.3)  # every run takes a while, so the queue is still full when the first fails
        if len(started) == 1:
            raise RuntimeError(f"boom in {config.label}")
        return runner.TrackingResult(config=config, frames=pd.DataFrame(), timing={})

    monkeypatch.setattr(runner, "_run_one", failing)
    configs = [cfg(seed=s) for s in range(4)]
    with ThreadPoolExecutor(max_workers=1) as pool:
        with pytest.raises(RuntimeError, match="boom"):
            run(configs, store=tmp_path / "s", executor=pool, progress=False)
    # The single worker may already have taken the second run when the failure is seen; the
    # third and fourth must never start.
    assert len(started) <= 2
    assert not list((tmp_path / "s").rglob("*.parquet"))


def test_a_worker_running_other_code_is_refused(monkeypatch, tmp_path):
    """The sweep's source hash travels with each run; a worker whose own differs (another
    gimbal-lab on a cluster's machine) refuses the run, naming both, and nothing is stored.
    Here the spawned workers hash the real source and this process a patched one."""
    monkeypatch.setattr(runner, "source_hash", lambda: "f" * 64)
    with pytest.raises(runner.SourceMismatch, match="runs gimbal_lab source [0-9a-f]{12}, the sweep's is ffffffffffff"):
        run(CONFIGS[:2], store=tmp_path / "s", jobs=2, progress=False)
    assert not list((tmp_path / "s").rglob("*.parquet"))


def test_run_rejects_bad_executor_and_store(tmp_path):
    with pytest.raises(TypeError, match="executor must be a concurrent.futures.Executor, got str"):
        run([cfg()], executor="tcp://localhost:8786", progress=False)
    with pytest.raises(ValueError, match="store root must be a non-empty path"):
        run([cfg()], store="", progress=False)
    with pytest.raises(ValueError, match="store root must be a non-empty path"):
        ResultsStore("   ")
    assert run([], jobs=1) == []


@pytest.mark.parametrize("address", ["", "  ", None, 8786])
def test_dask_executor_rejects_bad_addresses(address):
    with pytest.raises(ValueError, match="scheduler address must be a non-empty string"):
        dask_executor(address)


@pytest.mark.parametrize("path", ["", "   "])
def test_staged_folder_rejects_empty_paths(path):
    with pytest.raises(ValueError, match="output folder must be a non-empty path"):
        staged_folder(path)


def test_run_interrupted_says_what_was_kept(tmp_path):
    exc = RunInterrupted(2, 5, ResultsStore(tmp_path / "s"))
    assert isinstance(exc, KeyboardInterrupt)
    assert (exc.kept, exc.total) == (2, 5)
    assert "2 of 5" in str(exc) and str(tmp_path / "s") in str(exc)
    assert "lost" in str(RunInterrupted(0, 3, None))


def test_source_hash_is_stable_hex():
    h = source_hash()
    assert re.fullmatch(r"[0-9a-f]{16}", h) and h == source_hash()


def test_a_worker_keeps_at_most_max_renderers_and_closes_the_least_recently_used(monkeypatch):
    """Renderers are shared by runs with one renderer_key; beyond MAX_RENDERERS the least recently
    used is closed (a fisheye renderer holds one GL context per cube face)."""
    made, closed = [], []

    class Fake:
        def __init__(self, config):
            self.config = config
            made.append(self)

        def close(self):
            closed.append(self)

    monkeypatch.setattr(runner, "make_renderer", Fake)
    monkeypatch.setattr(runner, "_RENDERERS", {})
    configs = [TrackingConfig().with_(target__sphere_radius_m=0.1 * (1 + i)) for i in range(runner.MAX_RENDERERS + 2)]
    first = runner._renderer_for(configs[0])
    assert runner._renderer_for(TrackingConfig(seed=9, pointing=Pointing("paper"))) is first  # same key: shared
    for c in configs[1:runner.MAX_RENDERERS]:
        runner._renderer_for(c)
    assert runner._renderer_for(configs[0]) is first and not closed  # used again: now the most recent
    runner._renderer_for(configs[runner.MAX_RENDERERS])
    assert [r.config for r in closed] == [configs[1]]  # the least recently used went
    runner._renderer_for(configs[runner.MAX_RENDERERS + 1])
    assert [r.config for r in closed] == [configs[1], configs[2]]
    assert len(runner._RENDERERS) == runner.MAX_RENDERERS and len(made) == runner.MAX_RENDERERS + 2


@pytest.mark.parametrize("lands", ["after the files", "before the sidecar"])
def test_ctrl_c_while_a_run_is_being_stored_counts_it_exactly_when_it_is_whole(tmp_path, monkeypatch, lands):
    """Ctrl-C can land inside ``store.save``: after both files are written the run is kept and
    counted; before its sidecar is written it is neither (its table alone is not a stored run)."""
    configs = [cfg(seed=70), cfg(seed=71)]
    original = ResultsStore.save

    def save_then_interrupt(self, result):
        if result.config.seed == 71:
            if lands == "after the files":
                original(self, result)
            else:
                table, _ = self.paths(result.config)
                result.frames.to_parquet(table, index=False)
            raise KeyboardInterrupt
        original(self, result)

    monkeypatch.setattr(ResultsStore, "save", save_then_interrupt)
    with pytest.raises(RunInterrupted) as caught:
        run(configs, store=tmp_path / "s", jobs=1, progress=False)
    expected = 2 if lands == "after the files" else 1
    assert (caught.value.kept, caught.value.total) == (expected, 2)
    assert len(list((tmp_path / "s" / "runs").glob("*.json"))) == expected


def test_a_script_piped_to_python_is_refused_before_any_worker_dies():
    """Spawned workers re-import the main script by its path; ``python -`` has none on disk."""
    script = ("from gimbal_lab.runner import run\n"
              "from gimbal_lab.simulation import TrackingConfig\n"
              "run([TrackingConfig(revolutions=0.1, seed=s) for s in range(2)], jobs=2, progress=False)\n")
    done = subprocess.run([sys.executable, "-"], input=script, capture_output=True, text=True, timeout=120)
    assert done.returncode != 0
    assert "not a file" in done.stderr and "jobs=1" in done.stderr
    assert "worker process died" not in done.stderr
