"""The runner: the results store (round trip, reuse, corrupt entries, source-hash keying), local
and Dask executors giving the same frames as one process, Ctrl-C and SIGKILL of a running sweep
(no orphan workers, resume), staged output folders, and bad inputs.

Every run here is tiny (160 × 120 px, a few frames to a few revolutions) so the file stays fast
on two cores; the subprocess tests run real spawned worker pools.
"""

from __future__ import annotations

import contextlib
import hashlib
import io
import json
import logging
import os
import re
import shutil
import signal
import stat
import subprocess
import sys
import textwrap
import time
import warnings
from pathlib import Path
from typing import NamedTuple

import numpy as np
import pandas as pd
import pytest
from pandas.testing import assert_frame_equal

from gimbal_lab import runner
from gimbal_lab.config import Pointing
from gimbal_lab.runner import ResultsStore, RunInterrupted, dask_executor, run, source_hash
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
    """Damage the stored entry of ``c`` (``other`` is a stored run of the same length); return the
    file the warning must name."""
    table, sidecar = store.paths(c)
    if kind == "garbage sidecar":
        sidecar.write_text("{ this is not JSON")
        return sidecar
    if kind == "sidecar not text":
        sidecar.write_bytes(b"\xff\xfe\x00garbage")
        return sidecar
    if kind == "sidecar of another format":
        sidecar.write_text(json.dumps([1, 2, 3]))
        return sidecar
    if kind == "sidecar of another config":
        other_table, other_sidecar = store.paths(other)
        shutil.copyfile(other_sidecar, sidecar)
        shutil.copyfile(other_table, table)
        return sidecar
    if kind == "table of another run":  # same length, valid Parquet, valid page checksums
        shutil.copyfile(store.paths(other)[0], table)
        return table
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
    if kind == "folder in place of the table":
        table.unlink()
        (table / "x").mkdir(parents=True)
        return table
    if kind == "folder in place of the sidecar":
        sidecar.unlink()
        (sidecar / "x").mkdir(parents=True)
        return sidecar
    raise AssertionError(kind)


def _aside(path: Path) -> Path:
    return path.with_name(path.name + ".corrupt")


@pytest.mark.parametrize("kind", ["garbage sidecar", "sidecar not text", "sidecar of another format",
                                  "sidecar of another config", "sidecar of the flat config", "table of another run", "truncated parquet",
                                  "empty parquet", "parquet with fewer frames", "parquet missing",
                                  "folder in place of the table", "folder in place of the sidecar"])
def test_corrupt_entry_is_moved_aside_with_a_warning_and_recomputed(tmp_path, monkeypatch, kind):
    c, other = cfg(seed=9), cfg(seed=10)
    store = ResultsStore(tmp_path / "store")
    clean = run([c, other], store=store, jobs=1, progress=False)
    bad = _corrupt(kind, store, c, other)
    table, sidecar = store.paths(c)
    damaged = bad.read_bytes() if bad.is_file() else None

    with pytest.warns(RuntimeWarning, match=re.escape(str(bad))) as caught:
        assert store.load(c) is None
    assert len(caught) == 1 and "the run is recomputed" in str(caught[0].message)
    # moved aside, both files of the entry (the one that failed kept as it was, for a post-mortem)
    assert not os.path.lexists(table) and not os.path.lexists(sidecar) and _aside(sidecar).exists()
    assert _aside(table).exists() == (kind != "parquet missing")
    assert damaged is None or _aside(bad).read_bytes() == damaged

    calls = count_runs(monkeypatch)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # nothing left to warn about: the run is simply missing
        [again] = run([c], store=store, jobs=1, progress=False)
    assert calls == [c]  # recomputed, not served
    assert_frame_equal(again.frames, clean[0].frames, check_exact=True)

    # the recomputed run repaired the entry: it now loads silently, and the other entry is intact
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert_frame_equal(store.load(c).frames, clean[0].frames, check_exact=True)
        assert_frame_equal(store.load(other).frames, clean[1].frames, check_exact=True)


def test_a_corrupt_entry_met_by_a_sweep_is_recomputed_with_one_warning(tmp_path, monkeypatch):
    c = cfg(seed=14)
    store = ResultsStore(tmp_path / "store")
    [clean] = run([c], store=store, jobs=1, progress=False)
    bad = _corrupt("truncated parquet", store, c, None)
    calls = count_runs(monkeypatch)
    with pytest.warns(RuntimeWarning, match=re.escape(str(bad))) as caught:
        [again] = run([c], store=store, jobs=1, progress=False)
    assert len([w for w in caught if "results store" in str(w.message)]) == 1
    assert calls == [c]
    assert_frame_equal(again.frames, clean.frames, check_exact=True)


def test_an_entry_another_process_is_writing_is_left_to_it(tmp_path):
    """A corrupt-looking entry whose run another process has claimed may be half replaced by that
    process: it is not served and not moved aside; once the claim is released it is."""
    c = cfg(seed=29)
    store, other = ResultsStore(tmp_path / "store"), ResultsStore(tmp_path / "store")
    run([c], store=store, jobs=1, progress=False)
    bad = _corrupt("truncated parquet", store, c, None)
    assert other.claim(c)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert store.load(c) is None
    assert bad.exists() and not _aside(bad).exists()
    other.release(c)
    with pytest.warns(RuntimeWarning, match=re.escape(str(bad))):
        assert store.load(c) is None
    assert _aside(bad).exists()


def _forge(store: ResultsStore, c: TrackingConfig, frames: pd.DataFrame) -> Path:
    """Store ``frames`` as the table of ``c`` with a sidecar that agrees (digest, row count and the
    sidecar's own digest), as a writer with a bug would: only the checks of the table against the
    config can catch it."""
    table, sidecar = store.paths(c)
    buffer = io.BytesIO()
    frames.to_parquet(buffer, index=False)
    data = buffer.getvalue()
    table.write_bytes(data)
    meta = json.loads(sidecar.read_text())
    meta.update(table_sha256=hashlib.sha256(data).hexdigest(), frames=len(frames))
    meta.pop("sidecar_digest")
    meta["sidecar_digest"] = runner._seal(meta, runner._store_key())
    sidecar.write_text(json.dumps(meta))
    return table


def _nan_table(frames: pd.DataFrame) -> pd.DataFrame:
    return pd.DataFrame(np.nan, index=frames.index, columns=frames.columns)


#: Tables of the right length that are not what a run of the config makes; each must be caught
#: by the schema or frame checks alone (the sidecar is forged to agree with the table).
FORGED = {
    "a column missing": (lambda f: f.drop(columns="true_z_m"), "missing 'true_z_m'"),
    "an unknown column": (lambda f: f.assign(extra_m=1.0), "unknown 'extra_m'"),
    "columns reordered": (lambda f: f[list(f.columns[::-1])], "another order"),
    "strings in a column": (lambda f: f.assign(true_z_m=f["true_z_m"].astype(str)), "dtypes: true_z_m is "),
    "all NaN": (_nan_table, "frame is float64, not int64"),
    "booleans as integers": (lambda f: f.assign(detected=f["detected"].astype("int64")), "detected is int64"),
    "fewer frames": (lambda f: f.iloc[:3], "holds 3 frames, its config has 6"),
    "frames renumbered": (lambda f: f.assign(frame=f["frame"] + 1), "row 0 is frame 1"),
    "a frame repeated": (lambda f: f.iloc[[0, 1, 1, 3, 4, 5]].reset_index(drop=True), "row 2 is frame 1"),
    "times one frame late": (lambda f: f.assign(t_s=f["t_s"] + 1 / 30), "frame 0 is at t_s"),
    "a time NaN": (lambda f: f.assign(t_s=f["t_s"].where(f["frame"] != 4)), "frame 4 is at t_s = nan"),
}


@pytest.mark.parametrize("kind", list(FORGED))
def test_a_table_that_does_not_fit_its_config_is_never_served(tmp_path, monkeypatch, kind):
    c = cfg(seed=15)
    store = ResultsStore(tmp_path / "store")
    [clean] = run([c], store=store, jobs=1, progress=False)
    change, why = FORGED[kind]
    table = _forge(store, c, change(clean.frames.copy()))
    with pytest.warns(RuntimeWarning, match=re.escape(str(table)) + ".*does not fit its config.*" + re.escape(why)):
        assert store.load(c) is None
    assert _aside(table).exists() and not table.exists()
    calls = count_runs(monkeypatch)
    [again] = run([c], store=store, jobs=1, progress=False)
    assert calls == [c]
    assert_frame_equal(again.frames, clean.frames, check_exact=True)


def test_frame_times_within_rounding_are_accepted():
    """The tolerance on t_s admits k·(1/fps) (two roundings) besides k/fps, and nothing near a frame."""
    c = cfg(seed=0, camera__fps=30.0)
    frames = pd.DataFrame({name: np.zeros(c.n_frames, dtype) for name, dtype in runner.frame_schema().items()})
    k = np.arange(c.n_frames)
    runner.check_frames(frames.assign(frame=k, t_s=k / c.camera.fps), c)
    runner.check_frames(frames.assign(frame=k, t_s=k * (1.0 / c.camera.fps)), c)
    last = (c.n_frames - 1) / c.camera.fps
    runner.check_frames(frames.assign(frame=k, t_s=k / c.camera.fps + np.r_[np.zeros(c.n_frames - 1), np.spacing(last)]), c)
    with pytest.raises(ValueError, match="frame 5 is at t_s"):
        runner.check_frames(frames.assign(frame=k, t_s=k / c.camera.fps + np.r_[np.zeros(c.n_frames - 1), 1e-9]), c)


def test_the_frame_schema_is_the_simulations(reference):
    """Oracle: the frame tables the simulation makes (sphere and marker, lenses, modes)."""
    for result in reference:
        assert dict(result.frames.dtypes) == runner.frame_schema()
        runner.check_frames(result.frames, result.config)


def test_damaged_tables_are_never_served(tmp_path):
    """The campaign of issue 27: random single-bit flips and byte overwrites anywhere in a stored
    table. Read without the digest and without page-CRC verification (as the store did before),
    15 of these 200 loaded as valid tables with other numbers; with the CRCs alone none did, but
    68 loaded unchanged. Every one must now be detected by the digest (the bytes always change),
    moved aside and named in a warning."""
    c, other = cfg(seed=16), cfg(seed=17)
    store = ResultsStore(tmp_path / "store")
    clean, _ = run([c, other], store=store, jobs=1, progress=False)
    table, sidecar = store.paths(c)
    original, original_sidecar = table.read_bytes(), sidecar.read_bytes()
    rng = np.random.default_rng(27)
    detected = 0
    for i in range(200):
        data = bytearray(original)
        at = int(rng.integers(len(data)))
        if i % 2:
            data[at] ^= 1 << int(rng.integers(8))
        else:
            data[at] = (data[at] + int(rng.integers(1, 256))) % 256
        table.write_bytes(bytes(data))
        sidecar.write_bytes(original_sidecar)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            loaded = store.load(c)
        if loaded is not None:  # served: it must be the original table, not other numbers
            assert_frame_equal(loaded.frames, clean.frames, check_exact=True)
            continue
        assert any(str(table) in str(w.message) for w in caught), (i, at)
        assert _aside(table).read_bytes() == bytes(data) and not table.exists()
        detected += 1
    assert detected == 200

    # the whole table of another run of the same length, valid Parquet with valid page checksums
    shutil.copyfile(store.paths(other)[0], table)
    sidecar.write_bytes(original_sidecar)
    with pytest.warns(RuntimeWarning, match=re.escape(str(table)) + ".*does not match the SHA-256"):
        assert store.load(c) is None


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


def test_a_runs_folder_that_is_a_file_is_moved_aside(tmp_path, monkeypatch):
    root = tmp_path / "store"
    root.mkdir()
    (root / "runs").write_text("not a folder")
    with pytest.warns(RuntimeWarning, match=re.escape(str(root / "runs")) + " is not a folder"):
        store = ResultsStore(root)
    assert (root / "runs").is_dir() and (root / "runs.corrupt").read_text() == "not a folder"
    c = cfg(seed=18)
    calls = count_runs(monkeypatch)
    [result] = run([c], store=store, jobs=1, progress=False)
    assert calls == [c] and c in store


@contextlib.contextmanager
def _unwritable(folder: Path):
    """``folder`` cannot be written by this process: its write bits are removed, and when this
    process is root (which ignores them) it acts as the unprivileged user ``nobody`` meanwhile."""
    mode = folder.stat().st_mode
    os.chmod(folder, 0o555)
    try:
        if os.geteuid() == 0:
            os.setegid(65534)
            os.seteuid(65534)
            try:
                yield
            finally:
                os.seteuid(0)
                os.setegid(0)
        else:
            yield
    finally:
        os.chmod(folder, mode)


@pytest.fixture
def shared_tmp():
    """A temporary folder every user can reach (pytest's tmp_path is private to its owner)."""
    import tempfile

    path = Path(tempfile.mkdtemp(prefix="gimbal-store-"))
    path.chmod(0o755)
    yield path
    shutil.rmtree(path, ignore_errors=True)


def test_a_read_only_store_serves_what_it_holds_and_refuses_to_compute_in_one_line(shared_tmp, monkeypatch):
    stored, missing = cfg(seed=19), cfg(seed=20)
    root = shared_tmp / "store"
    [clean] = run([stored], store=root, jobs=1, progress=False)
    (root / "runs").chmod(0o755)
    source_hash()  # computed once per process; nobody could not read every file of the package
    calls = count_runs(monkeypatch)
    with _unwritable(root / "runs"):
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            [served] = run([stored], store=root, jobs=1, progress=False)
        with pytest.raises(runner.StoreError) as caught:
            run([stored, missing], store=root, jobs=1, progress=False)
    assert_frame_equal(served.frames, clean.frames, check_exact=True)
    assert calls == []  # refused before computing anything
    message = str(caught.value)
    assert "\n" not in message and str(root / "runs") in message and "Permission denied" in message, message
    assert message.startswith("results store: cannot write ") and "make the folder writable" in message

    # a store folder that cannot be made: the same error type, naming the folder
    with _unwritable(shared_tmp):
        with pytest.raises(runner.StoreError, match=re.escape(str(shared_tmp / "other")) + ".*Permission denied"):
            ResultsStore(shared_tmp / "other")
    (shared_tmp / "file").write_text("x")
    with pytest.raises(runner.StoreError, match=r"cannot create .*file.*(File exists|Not a directory)"):
        ResultsStore(shared_tmp / "file")


@pytest.mark.parametrize("mode", [0o700, 0o750, 0o755, 0o2770], ids=oct)
def test_entries_are_readable_by_whom_the_runs_folder_is(tmp_path, mode):
    root = tmp_path / "store"
    root.mkdir()
    root.chmod(mode)
    old_umask = os.umask(0o077)  # a private umask must not hide runs from a group the folder is shared with
    try:
        store = ResultsStore(root)
        c = cfg(seed=21)
        run([c], store=store, jobs=1, progress=False)
    finally:
        os.umask(old_umask)
    assert stat.S_IMODE(store.runs.stat().st_mode) == mode & 0o7777  # runs made like its store folder
    expected = 0o600 | (mode & 0o044)
    for path in store.paths(c):
        assert stat.S_IMODE(path.stat().st_mode) == expected, (oct(mode), path)


def _dead_pid() -> int:
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    return dead.pid


def _tag(host, pid, check=None) -> str:
    """The ``HOST~PID~RANDOM~CHECK`` part of a store's temporary name (or one with a wrong check)."""
    from gimbal_lab import outputs

    core = f"{host}~{pid}~0a1b"
    return f"{core}~{check or outputs._check_tag(core)}"


def test_temporary_files_of_killed_writers_are_removed_and_live_ones_kept(tmp_path):
    store = ResultsStore(tmp_path / "store")
    host, dead, live = runner._HOST, _dead_pid(), os.getppid()
    assert runner._tmp_name(store.runs / "a.json").name.startswith(f".a.json~{host}~{os.getpid()}~")
    files = {
        f".a.parquet~{_tag(host, dead)}.tmp": False,  # its writer on this machine is gone
        f".a.parquet~{_tag(host, live)}.tmp": True,  # a live writer's
        f".a.json~{_tag('otherhost', dead)}.tmp": True,  # another machine's: judged by age only
        f".e.json~{_tag('otherhost', dead)}.tmp": False,  # another machine's, older than TMP_MAX_AGE_S
        f".d.parquet~{_tag(host, live)}.tmp": False,  # live pid, but older than any write lasts
        # named like the store's temporary files but not made by it (no or a wrong check tag):
        # never removed, however old or dead their "writer"
        ".b.parquet.x1y2z3.tmp": True,
        ".c.parquet.x1y2z3.tmp": True,
        f".f.parquet~{host}~{dead}~0a1b.tmp": True,
        f".g.parquet~{_tag(host, dead, 'ffffff')}.tmp": True,
    }
    old_s = time.time() - runner.TMP_MAX_AGE_S - 60
    for name in files:
        (store.runs / name).write_bytes(b"partial")
        if name.startswith((".c.", ".d.", ".e.", ".f.", ".g.")):
            os.utime(store.runs / name, (old_s, old_s))
    ResultsStore(store.root)
    left = {p.name for p in store.runs.iterdir()}
    assert left == {name for name, kept in files.items() if kept}


def _claim_record(**changes) -> dict:
    pid = changes.get("pid", os.getpid())
    record = {"host": runner._HOST, "boot": runner._BOOT_ID, "pid": pid, "start": runner._start_ticks(pid),
              "token": "0" * 16}
    return {**record, **changes}


def test_claims_are_exclusive_and_stale_ones_are_taken_over(tmp_path):
    c = cfg(seed=22)
    a, b = ResultsStore(tmp_path / "store"), ResultsStore(tmp_path / "store")
    claim = a.runs / f"{a.key(c)}.claim"
    assert a.claim(c) and a.claim(c) and a.holds(c)
    owner = json.loads(claim.read_text())
    assert owner["pid"] == os.getpid() and owner["host"] == runner._HOST
    assert not b.claim(c)  # a live holder (another object of this process counts as another holder)
    assert len(list(a.runs.glob(".owner~*.lock"))) == 1  # a's lock, which its claim names
    assert not runner._lock_is_free(a.runs / owner["lock"])
    a.release(c)
    assert not claim.exists() and b.claim(c)
    b.release_all()
    assert not claim.exists() and not list(a.runs.glob(".owner~*"))  # no claim held: no lock left

    # another gimbal-lab run: a live process holding its store lock (as ResultsStore._owner_lock makes it)
    live = subprocess.Popen([sys.executable, "-c", textwrap.dedent(f"""
        import fcntl, os, sys, time
        fd = os.open({str(a.runs / ".owner~live.lock")!r}, os.O_RDWR | os.O_CREAT)
        fcntl.flock(fd, fcntl.LOCK_EX)
        print("locked", flush=True)
        time.sleep(60)
    """)], stdout=subprocess.PIPE, text=True)
    try:
        assert live.stdout.readline() == "locked\n"
        lock = ".owner~live.lock"
        cases = {
            "a live process": (_claim_record(pid=live.pid, lock=lock), 0, False),
            "a dead process": (_claim_record(pid=_dead_pid(), start=None, lock=lock), 0, True),
            "a reused pid": (_claim_record(pid=live.pid, lock=lock, start=(runner._start_ticks(live.pid) or 0) + 1), 0,
                             True),
            "this machine before a restart": (_claim_record(pid=live.pid, lock=lock, boot="another boot"), 0, True),
            "another machine, refreshed": (_claim_record(host="elsewhere"), 0, False),
            "another machine, not refreshed": (_claim_record(host="elsewhere"), runner.CLAIM_STALE_S + 60, True),
            "an owner that died writing it": ({}, runner.CLAIM_STALE_S + 60, True),
        }
        for name, (record, age_s, stale) in cases.items():
            claim.write_text(json.dumps(record) if record else "")
            os.utime(claim, (time.time() - age_s,) * 2)
            with warnings.catch_warnings():
                warnings.simplefilter("error")  # an owner that is merely gone is taken over silently
                assert a.claim(c) == stale, name
            assert claim.exists()
            if stale:
                assert json.loads(claim.read_text())["pid"] == os.getpid(), name
                a.release(c)
                assert not claim.exists()
    finally:
        live.kill()
        live.wait()


def test_a_claim_held_elsewhere_is_waited_for_then_reused(tmp_path, monkeypatch):
    """A run another process claimed is not computed: the sweep waits and loads the entry once it
    lands (here another store object plays the other process, finishing the run from a thread)."""
    import threading

    c, d = cfg(seed=23), cfg(seed=24)
    other = ResultsStore(tmp_path / "store")
    [result] = run([c], jobs=1, progress=False)  # computed without a store, as the other process would
    assert other.claim(c)

    def finish_later():
        time.sleep(1.0)
        other.save(result)
        other.release(c)

    monkeypatch.setattr(runner, "CLAIM_POLL_S", 0.05)
    calls = count_runs(monkeypatch)
    thread = threading.Thread(target=finish_later)
    thread.start()
    try:
        got = run([c, d], store=tmp_path / "store", jobs=1, progress=False)
    finally:
        thread.join()
    assert calls == [d]
    assert_frame_equal(got[0].frames, result.frames, check_exact=True)
    assert not list((tmp_path / "store" / "runs").glob("*.claim"))


TWO_SWEEPS_SCRIPT = textwrap.dedent('''
    import hashlib, json, os, sys, time
    from pathlib import Path

    from gimbal_lab import runner
    from gimbal_lab.simulation import TrackingConfig

    store, configs_path, log_path, go = sys.argv[1:5]
    configs = [TrackingConfig.from_dict(d) for d in json.loads(Path(configs_path).read_text())]
    original = runner._run_one

    def recorded(config, source=None):
        with open(log_path, "a") as log:
            log.write(config.key + "\\n")
        time.sleep(0.5)  # every run overlaps the other sweep's
        return original(config, source)

    runner._run_one = recorded
    runner.CLAIM_POLL_S = 0.05
    Path(log_path + ".ready").touch()
    while not os.path.exists(go):
        time.sleep(0.005)
    results = runner.run(configs, store=store, jobs=1, progress=False)
    digest = hashlib.sha256(b"".join(r.frames.to_numpy(dtype=float).tobytes() for r in results)).hexdigest()
    print(json.dumps({"digest": digest}))
''')


def test_two_processes_on_one_store_compute_each_run_once(tmp_path):
    configs = [cfg(seed=s) for s in range(25, 29)]
    (tmp_path / "sweep.py").write_text(TWO_SWEEPS_SCRIPT)
    (tmp_path / "configs.json").write_text(json.dumps([c.to_dict() for c in configs]))
    env = {**os.environ, "PYOPENGL_PLATFORM": "egl", "LP_NUM_THREADS": "1"}
    go = tmp_path / "go"
    procs = [subprocess.Popen([sys.executable, str(tmp_path / "sweep.py"), str(tmp_path / "store"),
                               str(tmp_path / "configs.json"), str(tmp_path / f"computed-{i}.txt"), str(go)],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env) for i in range(2)]
    deadline = time.monotonic() + 120
    while not all((tmp_path / f"computed-{i}.txt.ready").exists() for i in range(2)):  # both past their imports
        assert time.monotonic() < deadline and all(p.poll() is None for p in procs), [p.poll() for p in procs]
        time.sleep(0.02)
    go.touch()
    outputs = [p.communicate(timeout=300) for p in procs]
    for p, (out, err) in zip(procs, outputs):
        assert p.returncode == 0, err
    computed = [(tmp_path / f"computed-{i}.txt").read_text().split() if (tmp_path / f"computed-{i}.txt").exists()
                else [] for i in range(2)]
    assert sorted(computed[0] + computed[1]) == sorted(c.key for c in configs)  # each run once, by one of them
    assert computed[0] and computed[1], computed  # both took part: the test did race them
    digests = {json.loads(out.splitlines()[-1])["digest"] for out, _ in outputs}
    assert len(digests) == 1  # both return the same tables
    clean = run(configs, jobs=1, progress=False)
    stored = ResultsStore(tmp_path / "store")
    for result in clean:
        assert_frame_equal(stored.load(result.config).frames, result.frames, check_exact=True)
    assert not list(stored.runs.glob("*.claim")) and not list(stored.runs.glob(".*.tmp"))


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


def test_stopping_a_pool_ends_its_workers_and_its_manager_thread_before_returning(monkeypatch):
    """Ctrl-C, SIGTERM and a dead worker stop the local pool with ``_stop_pool``. When it returns,
    the workers are gone and so is the pool's manager thread: a thread still running then races
    with the interpreter's exit hook for its wake-up pipe (an "Exception ignored … Bad file
    descriptor" after the command's last line). The manager thread is made 1 s slower to wind
    up after its workers die, as on a loaded machine; it usually ends within the workers' join."""
    from concurrent.futures import process
    from concurrent.futures.process import BrokenProcessPool

    wind_up = process._ExecutorManagerThread.terminate_broken

    def slow_wind_up(self, *args, **kwargs):
        time.sleep(1.0)
        return wind_up(self, *args, **kwargs)

    monkeypatch.setattr(process._ExecutorManagerThread, "terminate_broken", slow_wind_up)
    pool = runner._local_pool(1)
    busy = pool.submit(time.sleep, 60)
    queued = pool.submit(time.sleep, 60)
    deadline = time.monotonic() + 60
    while not busy.running() and time.monotonic() < deadline:
        time.sleep(0.05)
    workers, manager = list(pool._processes.values()), pool._executor_manager_thread
    assert busy.running() and manager.is_alive()
    started = time.monotonic()
    runner._stop_pool(pool)
    assert time.monotonic() - started < 10  # not the 60 s sleep
    assert not manager.is_alive() and not any(w.is_alive() for w in workers)
    assert queued.cancelled() or isinstance(queued.exception(timeout=0), BrokenProcessPool)
    assert isinstance(busy.exception(timeout=0), BrokenProcessPool)


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


@pytest.mark.parametrize("story", ["files edited during the sweep", "other code on the workers"])
def test_a_worker_running_other_code_is_refused(monkeypatch, tmp_path, story):
    """The sweep's source hash travels with each run; a worker whose own differs refuses the run,
    naming both, nothing of it is stored, and the error says what is kept and how to go on. Here
    the spawned workers hash the real source and this process a patched one; when the package's
    files on disk hash like the workers' (an edit after the sweep started) the message says so."""
    monkeypatch.setattr(runner, "source_hash", lambda: "f" * 64)
    if story == "other code on the workers":
        monkeypatch.setattr(runner, "_hash_package", lambda: "e" * 16)
    store = tmp_path / "s"
    run(CONFIGS[:1], store=store, jobs=1, progress=False)  # in this process: kept under the sweep's source
    with pytest.raises(runner.SourceMismatch) as caught:
        run(CONFIGS, store=store, jobs=2, progress=False)
    message = str(caught.value)
    assert isinstance(caught.value, runner.SweepFailed) and "\n" not in message
    assert (caught.value.kept, caught.value.total) == (1, 3)
    assert len(list((store / "runs").glob("*.parquet"))) == 1
    if story == "other code on the workers":
        assert re.search(r"a worker \(pid \d+\) runs gimbal_lab source [0-9a-f]{12}, the sweep's is ffffffffffff: "
                         r"install the same gimbal-lab on every worker", message), message
        assert message.endswith(f"1 of 3 runs are finished and kept in {store}; run the same command again to "
                                "resume (it reuses them and computes the other 2)"), message
    else:
        now = runner._hash_package()[:12]
        assert message.startswith(f"gimbal_lab's files changed during the sweep (now source {now}"
                                  ", the sweep's ffffffffffff; a file edited while it ran?): 1 of 3 runs are finished "
                                  f"and kept in {store} under the source the sweep started with; run the same command "
                                  "again: it computes every run with the code as it is now"), message


def _run_or_die(config, source=None):
    """In a spawned worker: the real run, except for seeds >= 100, whose worker dies at once."""
    if config.seed >= 100:
        os._exit(3)
    return runner._run_one(config, source)


def test_workers_dying_again_and_again_stop_the_sweep_saying_what_is_kept(tmp_path, monkeypatch):
    """Every pool breaks on the run whose worker dies; after MAX_POOL_RESTARTS new pools the sweep
    stops with WorkersDied, its one-line message counting the runs kept (those in the store).
    One restart allowed, not the default 2: each new pool spawns workers that import the lab, and
    giving up after N new pools is the same code for any N >= 1."""
    monkeypatch.setattr(runner, "_run_one", _run_or_die)
    monkeypatch.setattr(runner, "MAX_POOL_RESTARTS", 1)
    store = tmp_path / "s"
    configs = [cfg(seed=80), cfg(seed=81), cfg(seed=100)]
    with pytest.warns(RuntimeWarning, match="a worker process died"):
        with pytest.raises(runner.WorkersDied) as caught:
            run(configs, store=store, jobs=2, progress=False)
    exc = caught.value
    kept = len(list((store / "runs").glob("*.json")))
    assert (exc.kept, exc.total) == (kept, 3)
    message = str(exc)
    assert "\n" not in message
    assert message.startswith(f"worker processes died {runner.MAX_POOL_RESTARTS + 1} time(s) in this sweep"), message
    assert message.endswith(f"{kept} of 3 runs are finished and kept in {store}; run the same command again to resume "
                            f"(it reuses them and computes the other {3 - kept})"), message
    assert not list((store / "runs").glob("*.claim"))


def test_a_result_that_is_not_the_run_sent_is_refused_naming_both(tmp_path, monkeypatch):
    """What a worker returns (here through a thread pool, as from a Dask cluster) is checked
    against the config sent before anything is stored."""
    from concurrent.futures import ThreadPoolExecutor

    sent, other = cfg(seed=90), cfg(seed=91)
    [wrong] = run([other], jobs=1, progress=False)
    monkeypatch.setattr(runner, "_run_one", lambda config, source=None: wrong)
    with ThreadPoolExecutor(max_workers=1) as pool:
        with pytest.raises(runner.ResultMismatch) as caught:
            run([sent], store=tmp_path / "s", executor=pool, progress=False)
    message = str(caught.value)
    assert f"the result of {other.label} seed 91 (key {other.key})" in message, message
    assert f"the run sent as {sent.label} seed 90 (key {sent.key})" in message, message
    assert "0 of 1 runs are finished" in message and "\n" not in message
    assert not list((tmp_path / "s").rglob("*.parquet"))

    short = runner.TrackingResult(config=sent, frames=wrong.frames.iloc[:3], timing={})
    monkeypatch.setattr(runner, "_run_one", lambda config, source=None: short)
    with ThreadPoolExecutor(max_workers=1) as pool:
        with pytest.raises(runner.ResultMismatch, match=f"key {sent.key}.*not a valid frame table: it holds 3 frames"):
            run([sent], store=tmp_path / "s", executor=pool, progress=False)
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


def test_run_interrupted_says_what_was_kept_and_what_a_rerun_reuses(tmp_path):
    exc = RunInterrupted(2, 5, ResultsStore(tmp_path / "s"))
    assert isinstance(exc, KeyboardInterrupt)
    assert (exc.kept, exc.total) == (2, 5)
    assert str(exc) == (f"interrupted: 2 of 5 runs are finished and kept in {tmp_path / 's'}; run the same command "
                        "again to resume (it reuses them and computes the other 3)")
    # --no-cache (read=False): the same command would recompute everything; only a rerun without it reuses
    exc = RunInterrupted(2, 5, ResultsStore(tmp_path / "s", read=False))
    assert str(exc) == (f"interrupted: 2 of 5 runs are finished and kept in {tmp_path / 's'}; a rerun without "
                        "--no-cache (read=True) reuses them and computes the other 3, while the same command, with "
                        "--no-cache, recomputes all 5")
    assert str(RunInterrupted(0, 3, None)) == ("interrupted: 0 of 3 runs finished but no store was given: they are "
                                               "lost, and a rerun computes all 3")


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
