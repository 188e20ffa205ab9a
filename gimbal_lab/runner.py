"""Running many closed-loop configs: executors, the results store, progress, interruption.

* **Executors.** :func:`run` sends configs to any :class:`concurrent.futures.Executor`: by default
  a local pool of worker processes started with ``spawn`` (a process that created an OpenGL
  context must never fork), or e.g. a Dask cluster's executor
  (``distributed.Client(address).get_executor()``, see :func:`dask_executor`). Every worker keeps
  one scene renderer per camera, lens and target and reuses it across runs, and uses one llvmpipe
  thread (the fastest setting with one process per core). Every result a worker returns is checked
  against the config that was sent (same config, a valid frame table) before it is stored.
* **The results store** (:class:`ResultsStore`): one Parquet frame table and one JSON sidecar
  (config, package version, source hash, seed, timings, the table's SHA-256, and a digest of all
  of these, keyed under ``GIMBAL_LAB_STORE_KEY`` when set) per run, each written atomically
  (temporary file, then ``os.replace``). An entry is keyed by the config *and*
  a hash of the package's source, so any change to the code recomputes. An entry is served only
  if its table's bytes match the digest in its sidecar and its columns, dtypes and frame times
  fit the config; anything else is moved aside (``NAME.corrupt``), named in a warning and
  recomputed. Nothing is ever unpickled from disk. Processes sharing a store claim each run
  before computing it, so no run is computed twice.
* **Interruption and failure.** Finished runs are stored the moment they finish. Ctrl-C cancels
  what is queued, stops the local workers at once and raises :class:`RunInterrupted`; a sweep that
  cannot go on (workers dying again and again, workers running other code, a result that does not
  fit its config) raises a :class:`SweepFailed`; a store that cannot be written raises
  :class:`StoreError`. Each says in one line how many runs are kept and how to resume. Local
  workers exit by themselves when the parent process dies (even by SIGKILL).
"""

from __future__ import annotations

import contextlib
import errno
import functools
import hashlib
import hmac
import json
import logging
import os
import secrets
import shutil
import signal
import socket
import stat
import sys
import threading
import time
import warnings
from concurrent.futures import Executor, FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from multiprocessing import get_context
from pathlib import Path

import numpy as np
import pandas as pd

from .outputs import folder_lock as _folder_lock
from .outputs import is_own_temporary as _is_own_temporary
from .outputs import unique_tag as _unique_tag
from .simulation import TrackingConfig, TrackingResult, make_renderer, renderer_key, simulate

__all__ = ["ResultsStore", "RunInterrupted", "SweepFailed", "SourceMismatch", "WorkersDied", "ResultMismatch",
           "StoreError", "run", "source_hash", "dask_executor",
           "default_store_root", "default_jobs", "checkout_root", "STORE_ENV", "JOBS_ENV", "STORE_KEY_ENV"]

log = logging.getLogger(__name__)

#: 2: the sidecar records the table's SHA-256 (``table_sha256``), and tables carry page CRCs.
#: 3: the sidecar also records a digest of all its other fields (``sidecar_digest``): SHA-256, or
#: HMAC-SHA-256 under :data:`STORE_KEY_ENV`.
STORE_FORMAT = 3
#: Environment variable holding a secret key: when set, every sidecar's digest is an HMAC-SHA-256
#: under it, and only entries sealed with the same key are served (a shared store).
STORE_KEY_ENV = "GIMBAL_LAB_STORE_KEY"


def _store_key() -> bytes | None:
    value = os.environ.get(STORE_KEY_ENV, "")
    return value.encode() if value else None


def _seal(fields: dict, key: bytes | None) -> dict:
    """The ``sidecar_digest`` of a sidecar's other ``fields``: over their canonical JSON (sorted
    keys, no spaces), SHA-256, or HMAC-SHA-256 under ``key``."""
    body = json.dumps(fields, sort_keys=True, separators=(",", ":")).encode()
    if key is None:
        return {"sha256": hashlib.sha256(body).hexdigest()}
    return {"hmac_sha256": hmac.new(key, body, hashlib.sha256).hexdigest()}


def _seal_problem(meta: dict) -> str | None:
    """Why a parsed sidecar's ``sidecar_digest`` does not vouch for its other fields, or None."""
    fields = {k: v for k, v in meta.items() if k != "sidecar_digest"}
    seal, key = meta.get("sidecar_digest"), _store_key()
    if not isinstance(seal, dict) or not seal:
        return "records no digest of itself"
    if "hmac_sha256" in seal and key is None:
        return f"is sealed with a key ({STORE_KEY_ENV}) that is not set here"
    if key is not None and "hmac_sha256" not in seal:
        return f"is not sealed with {STORE_KEY_ENV} (set here: only entries sealed with it are served)"
    if not hmac.compare_digest(json.dumps(seal, sort_keys=True), json.dumps(_seal(fields, key), sort_keys=True)):
        what = "its keyed digest (another key, or edited)" if key is not None else "the digest it records"
        return f"does not match {what}: a field was damaged or edited"
    return None


def _hash_package() -> str:
    """SHA-256 (hex, 16 characters) of every ``.py`` file of the package as it is on disk now."""
    root = Path(__file__).resolve().parent
    digest = hashlib.sha256()
    for path in sorted(root.rglob("*.py")):
        digest.update(path.relative_to(root).as_posix().encode())
        digest.update(b"\0")
        digest.update(path.read_bytes())
        digest.update(b"\0")
    return digest.hexdigest()[:16]


@functools.lru_cache(maxsize=1)
def source_hash() -> str:
    """SHA-256 (hex, 16 characters) of every ``.py`` file of the installed package, path and bytes,
    taken once per process (the first time it is asked for)."""
    return _hash_package()


# ----------------------------------------------------------------------------------------------
# errors a command line prints in one line
# ----------------------------------------------------------------------------------------------
class StoreError(RuntimeError):
    """The results store cannot be used: ``path`` could not be created or written (``reason``).

    ``str()`` is one line naming the path, the cause and what to do.
    """

    def __init__(self, path, cause, doing: str = "write"):
        reason = cause.strerror if isinstance(cause, OSError) and cause.strerror else str(cause)
        super().__init__(str(path), reason, doing)  # all of it in args: it pickles
        self.path, self.reason, self.doing = Path(path), reason, doing

    def __str__(self) -> str:
        return (f"results store: cannot {self.doing} {self.path}: {self.reason} (make the folder writable, or give "
                "another store or output folder)")


def _resume_hint(kept: int, total: int, store: ResultsStore | None) -> str:
    """What a stopped sweep kept and what running it again does, in one sentence."""
    if store is None:
        return (f"{kept} of {total} runs finished but no store was given: they are lost, and a rerun computes "
                f"all {total}")
    others = total - kept
    where = f"{kept} of {total} runs are finished and kept in {store.root}"
    if store.read:
        return f"{where}; run the same command again to resume (it reuses them and computes the other {others})"
    return (f"{where}; a rerun without --no-cache (read=True) reuses them and computes the other {others}, while "
            f"the same command, with --no-cache, recomputes all {total}")


class RunInterrupted(KeyboardInterrupt):
    """Ctrl-C stopped :func:`run`; ``kept`` of ``total`` runs are finished (and stored).

    ``str()`` says exactly what a rerun reuses: with a store that is read, the same command
    resumes; with ``read=False`` (``--no-cache``) only a rerun without it reuses the kept runs.
    """

    def __init__(self, kept: int, total: int, store: ResultsStore | None):
        self.kept, self.total, self.store = kept, total, store
        super().__init__(f"interrupted: {_resume_hint(kept, total, store)}")

    def __str__(self) -> str:
        return self.args[0]


class SweepFailed(RuntimeError):
    """A sweep stopped on an error; ``kept`` of ``total`` runs were finished and stored first.

    Raised by :func:`run` after it stopped the workers; ``str()`` is one line: what went wrong,
    what is kept and how to resume. ``kept``, ``total`` and ``store`` are None when the error was
    made where they are not known (in a worker).
    """

    kept: int | None = None
    total: int | None = None
    store: ResultsStore | None = None

    def __str__(self) -> str:
        return str(self.args[0]) if self.args else ""

    def _stopped(self, kept: int, total: int, store, message: str):
        self.kept, self.total, self.store = kept, total, store
        self.args = (message, *self.args[1:])
        return self


class WorkersDied(SweepFailed):
    """Local worker processes kept dying (:data:`MAX_POOL_RESTARTS` new pools did not help), or a
    worker of an executor the runner cannot restart died."""


class ResultMismatch(SweepFailed):
    """A worker returned a result that is not the one of the config it was sent, or whose frame
    table does not fit that config; it is not stored."""


class SourceMismatch(SweepFailed):
    """A worker runs other gimbal_lab code than the process that keys and stores its results.

    Made in the worker with ``worker_source`` and ``sweep_source`` (the two source hashes);
    :func:`run` adds what is kept and whether the package's files changed during the sweep.
    """

    def __init__(self, message: str, worker_source: str | None = None, sweep_source: str | None = None):
        super().__init__(message, worker_source, sweep_source)
        self.worker_source, self.sweep_source = worker_source, sweep_source


# ----------------------------------------------------------------------------------------------
# the frame table a stored or returned result must hold
# ----------------------------------------------------------------------------------------------
def _frame_clock(config: TrackingConfig) -> tuple[int, float]:
    """The number of frames a run of ``config`` holds and its frame rate, Hz: the store's only use
    of the config's fields (its key comes from ``config.key``)."""
    return config.n_frames, config.camera.fps


#: Columns of the frame table that hold integers and booleans (``simulation.closed_loop`` writes
#: Python ints and bools there, and in the ``<method>_detected`` column of each family a run's
#: ``estimator.extra_methods`` adds); every other column holds float64.
_INTEGER_COLUMNS = frozenset({"frame", "revolution"})
_BOOLEAN_COLUMNS = frozenset({"detected", "alt_detected", "hidden", "partial", "at_limit_yaw", "at_limit_roll",
                               "at_limit_pitch"})


def frame_schema(config: TrackingConfig | None = None) -> dict[str, np.dtype]:
    """The frame table's columns, in order, and their dtypes (see :data:`gimbal_lab.simulation.FRAME_COLUMNS`):
    every run's, and with ``config`` the families its estimator adds
    (:func:`gimbal_lab.simulation.frame_columns`)."""
    from .simulation import _COLUMNS, frame_columns

    extra_flags = set() if config is None else {f"{m}_detected" for m in config.estimator.extra_methods}

    def dtype(name):
        return np.dtype("int64") if name in _INTEGER_COLUMNS else np.dtype(bool) \
            if name in _BOOLEAN_COLUMNS or name in extra_flags else np.dtype("float64")

    return {name: dtype(name) for name in (_COLUMNS if config is None else frame_columns(config))}


def _listed(names, limit: int = 3) -> str:
    names = list(names)
    return ", ".join(map(repr, names[:limit])) + (f" and {len(names) - limit} more" if len(names) > limit else "")


def check_frames(frames, config: TrackingConfig) -> None:
    """Raise ValueError unless ``frames`` is a frame table a run of ``config`` can have produced.

    Checked: the columns, in order, and their dtypes (:func:`frame_schema` of ``config``); one row per frame
    (``config.n_frames``); ``frame`` = 0, 1, …, n − 1; ``t_s`` = k / fps. The simulation computes
    t_s as one correctly rounded division (error ≤ ½ ulp) and Parquet stores float64 exactly, so
    the times must agree within 2 ε·t_last (ε: float64's machine epsilon), which also admits a
    writer that forms k · (1/fps) (two roundings). A frame's time off by as little as one frame
    (1/fps) is far outside it; a flip of a time's lowest bits is not, and is the digest's to catch.
    """
    if not isinstance(frames, pd.DataFrame):
        raise ValueError(f"it is a {type(frames).__name__}, not a frame table (pandas.DataFrame)")
    schema = frame_schema(config)
    columns = list(frames.columns)
    if columns != list(schema):
        missing = [c for c in schema if c not in frames.columns]
        extra = [c for c in columns if c not in schema]
        if missing or extra:
            raise ValueError("its columns are not the frame table's"
                             + (f": missing {_listed(missing)}" if missing else "")
                             + (f"{';' if missing else ':'} unknown {_listed(extra)}" if extra else ""))
        raise ValueError("its columns are the frame table's in another order (or repeated)")
    wrong = [f"{name} is {frames[name].dtype}, not {want}" for name, want in schema.items()
             if frames[name].dtype != want]
    if wrong:
        raise ValueError(f"wrong column dtypes: {'; '.join(wrong[:3])}" + (f" and {len(wrong) - 3} more"
                                                                           if len(wrong) > 3 else ""))
    n, fps = _frame_clock(config)
    if len(frames) != n:
        raise ValueError(f"it holds {len(frames)} frames, its config has {n}")
    k = np.arange(n)
    index = frames["frame"].to_numpy()
    if not np.array_equal(index, k):
        first = int(np.flatnonzero(index != k)[0])
        raise ValueError(f"row {first} is frame {index[first]}, not {first}")
    t_s = frames["t_s"].to_numpy()
    tolerance_s = 2.0 * np.finfo(float).eps * max((n - 1) / fps, 1.0 / fps)
    off = ~(np.abs(t_s - k / fps) <= tolerance_s)  # NaN counts as off
    if off.any():
        first = int(np.flatnonzero(off)[0])
        raise ValueError(f"frame {first} is at t_s = {float(t_s[first])!r} s, not {first}/{fps:g} Hz = "
                         f"{first / fps!r} s (within {tolerance_s:.1e} s)")


def _check_result(sent: TrackingConfig, result) -> None:
    """Raise :class:`ResultMismatch` unless ``result`` is the result of ``sent`` with a valid table."""
    if not isinstance(result, TrackingResult):
        raise ResultMismatch(f"a worker returned a {type(result).__name__}, not a TrackingResult, for the run sent as "
                             f"{sent.label} seed {sent.seed} (key {sent.key}); nothing of it is stored")
    got = result.config
    if not isinstance(got, TrackingConfig) or got != sent or got.key != sent.key:
        what = f"{got.label} seed {got.seed} (key {got.key})" if isinstance(got, TrackingConfig) else repr(got)
        raise ResultMismatch(f"a worker returned the result of {what} for the run sent as {sent.label} seed "
                             f"{sent.seed} (key {sent.key}); nothing of it is stored")
    try:
        check_frames(result.frames, sent)
    except ValueError as exc:
        raise ResultMismatch(f"a worker's result for {sent.label} seed {sent.seed} (key {sent.key}) is not a valid "
                             f"frame table: {exc}; nothing of it is stored") from None


# ----------------------------------------------------------------------------------------------
# files: atomic writes, leftovers of killed writers, modes
# ----------------------------------------------------------------------------------------------
#: This machine, as it appears in temporary and claim files (a name that is safe in a file name).
_HOST = "".join(ch if ch.isalnum() or ch in "-_" else "_" for ch in socket.gethostname()) or "host"


def _read_boot_id() -> str:
    try:
        return Path("/proc/sys/kernel/random/boot_id").read_text().strip()
    except OSError:
        return ""


_BOOT_ID = _read_boot_id()


def _proc_stat(pid: int) -> tuple[str, int] | None:
    """State and start time (clock ticks since boot) of process ``pid`` from Linux /proc, or None."""
    try:
        text = Path(f"/proc/{pid}/stat").read_text()
        fields = text[text.rindex(")") + 2:].split()
        return fields[0], int(fields[19])
    except (OSError, ValueError, IndexError):
        return None


def _start_ticks(pid: int) -> int | None:
    st = _proc_stat(pid)
    return None if st is None else st[1]


def _alive(pid: int, start: int | None = None) -> bool:
    """Is process ``pid`` running (not a zombie and, given ``start``, the process that started then)?"""
    if pid == os.getpid():
        return start is None or start == _start_ticks(pid)
    try:
        os.kill(pid, 0)
    except (ProcessLookupError, OverflowError):
        return False
    except PermissionError:
        pass
    st = _proc_stat(pid)
    if st is None:  # no /proc here: kill(0) is all there is
        return True
    return st[0] not in ("Z", "X") and (start is None or st[1] == start)


#: A temporary file of a writer on this machine whose process is gone is removed at once; one of
#: another machine (a store on a network file system) once it is older than this. A writer keeps
#: its temporary file for the time it takes to write one table (milliseconds), so an hour is far
#: beyond a write still in progress. Only names the lab made are removed (their check tag fits,
#: :func:`gimbal_lab.outputs.is_own_temporary`): a user's ``.x~y~1~z.tmp`` is never touched.
TMP_MAX_AGE_S = 3600.0


def _tmp_name(path: Path) -> Path:
    """A temporary name beside ``path``, unique to this process and call:
    ``.NAME~HOST~PID~RANDOM~CHECK.tmp``."""
    return path.with_name(f".{path.name}~{_unique_tag('~')}.tmp")


def _stale_tmp(name: str, mtime: float, now: float) -> bool:
    """Is the temporary file ``name`` a leftover of a killed writer (see :data:`TMP_MAX_AGE_S`)?"""
    parts = name[:-len(".tmp")].rsplit("~", 4)
    owner = _is_own_temporary("~".join(parts[1:]), "~") if len(parts) == 5 else None
    if owner is None:
        return False  # not a name the lab made
    return now - mtime > TMP_MAX_AGE_S or (owner[0] == _HOST and not _alive(owner[1]))


def _atomic_write(path: Path, data: bytes, mode: int = 0o644) -> None:
    """Write ``data`` to a temporary file beside ``path`` (its name unique to this process and call,
    created with O_EXCL, permissions ``mode``), then rename it over ``path``.

    No fsync: a file torn by a power cut fails its digest on the next load and is recomputed."""
    tmp = _tmp_name(path)
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    try:
        try:
            os.fchmod(fd, mode)
            view = memoryview(data)
            while view:
                view = view[os.write(fd, view):]
        finally:
            os.close(fd)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


def _remove(path: Path) -> None:
    """Remove a file, link or whole folder at ``path`` (nothing if there is none)."""
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path)
    else:
        with contextlib.suppress(FileNotFoundError):
            path.unlink()


def _table_bytes(frames: pd.DataFrame) -> bytes:
    """The Parquet file of a frame table, with page CRCs (pyarrow's ``write_page_checksum``)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    sink = pa.BufferOutputStream()
    pq.write_table(pa.Table.from_pandas(frames, preserve_index=False), sink, write_page_checksum=True)
    return sink.getvalue().to_pybytes()


def _parse_table(data: bytes) -> pd.DataFrame:
    import pyarrow as pa
    import pyarrow.parquet as pq

    return pq.read_table(pa.BufferReader(data), page_checksum_verification=True).to_pandas()


# ----------------------------------------------------------------------------------------------
# the results store
# ----------------------------------------------------------------------------------------------
#: A claim's owner refreshes its claim files' times this often while it holds them, and a claim
#: not refreshed for CLAIM_STALE_S is taken over (an owner on another machine, or a stopped one).
CLAIM_REFRESH_S = 30.0
CLAIM_STALE_S = 300.0
#: How often a sweep looks whether runs claimed by another process have landed or been released.
CLAIM_POLL_S = 0.5


class ResultsStore:
    """A folder of finished runs, one Parquet frame table + JSON sidecar per run.

    Parameters
    ----------
    root : path
        Folder of the store (created when missing). Entries live in ``root/runs``.
    read : bool
        False: never answer from disk (recompute everything) but still store what is computed.

    Raises
    ------
    StoreError
        ``root`` or ``root/runs`` cannot be created (a file of that name, no permission).

    Notes
    -----
    **Entries.** The entry of a config is ``runs/<key>.parquet`` and ``runs/<key>.json`` with
    key = SHA-256 of the config's key (its nested parts and schema version) and :func:`source_hash`. The table is written first, the
    sidecar last, so an entry without a sidecar is incomplete and simply recomputed.

    **What is served.** :meth:`load` reads the sidecar (this format; its ``sidecar_digest`` over
    every other field, the served ``timing`` included; this source hash, this config), then the
    table's bytes, whose SHA-256 must equal the sidecar's ``table_sha256``
    *before* they are parsed (the parsed bytes are the hashed ones), then checks the table against
    the config (:func:`check_frames`: columns, dtypes, one row per frame, frame numbers and times).
    Anything else is moved aside to ``NAME.corrupt`` (table and sidecar), named in a warning
    (:mod:`warnings` and the ``gimbal_lab.runner`` log) and recomputed. A folder in place of a
    file, or a file in place of ``runs``, is moved aside the same way.

    **Page checksums.** Tables are written with Parquet page CRCs and read with their
    verification on. A CRC covers one data page's bytes: it catches damage inside the pages, but
    not in the footer (schema, column names, offsets, statistics), nor a page header, nor a whole
    valid file put in another's place (a table copied over another run's carries valid CRCs). The
    digest in the sidecar covers every byte and ties the table to its config, so it is the guard;
    the CRCs let a table copied out of the store show page damage to any Parquet reader.

    **Keyed digests.** The digests guard against damage and mix-ups, not against someone who can
    write the store: they can rewrite a table, its ``table_sha256`` and the sidecar's digest
    alike. With :data:`STORE_KEY_ENV` set (``GIMBAL_LAB_STORE_KEY``, a secret shared by the store's
    trusted users), each sidecar is sealed with HMAC-SHA-256 under that key, which covers the
    table's SHA-256 too, and only entries sealed with the same key are served; others are moved
    aside and recomputed like any damaged entry.

    Measured
    without the digest, on 1,000 random single-bit flips and byte overwrites of one 35 kB table
    (the campaign of ``tests/test_runner.py``): read without CRC verification, 47 loaded as valid
    tables with other numbers; with it, none did, but 396 loaded unchanged (damage in statistics
    or metadata) and the rest failed to parse or failed :func:`check_frames`. With the digest,
    all 1,000 are caught before parsing.

    **Two processes on one store.** A run is computed only by the process that *claims* it: a
    ``runs/<key>.claim`` naming its owner (host, boot, pid, the pid's start time and executable),
    written whole under a temporary name and hard-linked into place (which fails if it exists;
    O_EXCL where links are not allowed), so a claim is never seen half written.
    Others wait for the entry instead of computing it, and take the claim over when it is stale:
    its owner is gone (same machine: the pid no longer runs or is another process; the machine
    restarted), or the claim was not refreshed for :data:`CLAIM_STALE_S` (owners refresh their
    claims every :data:`CLAIM_REFRESH_S` from a thread), which covers an owner on another machine.
    While it holds claims, a store object holds an exclusive ``flock`` on a lock file of its own
    (``runs/.owner~HOST~PID~RANDOM~CHECK.lock``) that its claims name. A claim that is not one the
    lab writes (not JSON, fields missing or of the wrong type), or that names a live process of
    this machine which does not hold the lock the claim names (not a gimbal-lab run, whatever its
    pid), is taken over at once with a warning naming it. Lock files nobody holds are removed.
    A claim file rather than an ``fcntl`` lock per run because a sweep on a pool holds a claim on
    every run it has queued (hundreds or thousands of them: one open file each would pass the usual
    limit of 1024) and a claim stays visible on disk. A sweep in one process claims one run at a
    time, so two of them share the work. Deciding a claim is stale and removing it happen under
    an ``fcntl.flock`` on the ``runs`` folder, so two processes never both take one over. A wrong
    judgement can only cost a run computed twice (deterministic, written atomically), never a
    wrong table. Only the claim's holder moves an entry aside, after reading it once more.

    **Leftovers.** Temporary files of writers killed mid-write are removed when a store is
    opened: at once when their writer (named in the file name) ran on this machine and is gone,
    otherwise once older than :data:`TMP_MAX_AGE_S` (no write lasts that long), so a file that is
    being written is never touched.

    **Permissions.** Entries get read permission for the group and for others exactly when the
    ``runs`` folder grants it to them (the owner reads and writes): a store folder made
    group-readable (``chmod g+rx`` or a setgid group folder) shares its runs with the group
    whatever the writer's umask, and one made with umask 077 stays private. A ``runs`` folder the
    store creates gets the permission bits of the store folder; the store folder itself is made
    with the umask.
    """

    def __init__(self, root, read: bool = True):
        self.read = bool(read)
        root = os.fspath(root)
        if not isinstance(root, str) or not root.strip():
            raise ValueError(f"store root must be a non-empty path, got {root!r}")
        self.root = Path(root)
        self.runs = self.root / "runs"
        self._claims: dict[str, tuple[Path, str]] = {}  # key -> (claim file, its token)
        self._claims_guard = threading.Lock()
        self._heartbeat: threading.Thread | None = None
        self._owner: tuple[int, str] | None = None  # (fd, name) of the lock this object holds while it claims
        self._open()

    @classmethod
    def default(cls, read: bool = True) -> ResultsStore:
        """The store at :func:`default_store_root`: ``$GIMBAL_LAB_STORE``, else ``results/store`` at
        the checkout's root (inside the checkout), else in the user's cache folder. The notebooks'
        store, and ``gimbal-lab run``'s without ``--store``."""
        return cls(default_store_root(), read=read)

    def __repr__(self) -> str:
        return f"ResultsStore({str(self.root)!r})"

    def __getstate__(self):
        state = self.__dict__.copy()  # claims belong to the process holding them
        state.update(_claims={}, _claims_guard=None, _heartbeat=None, _owner=None)
        return state

    def __setstate__(self, state):
        self.__dict__.update(state)
        self._claims_guard = threading.Lock()

    # -- opening --------------------------------------------------------------------------------
    def _open(self) -> None:
        try:
            self.root.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise StoreError(self.root, exc, "create") from exc
        if os.path.lexists(self.runs) and not self.runs.is_dir():
            self._move_aside([self.runs], self.runs, "is not a folder", then="every run is looked up anew")
        if not self.runs.is_dir():
            try:
                self.runs.mkdir()
                os.chmod(self.runs, stat.S_IMODE(self.root.stat().st_mode))
            except FileExistsError:
                pass  # made by another process meanwhile
            except OSError as exc:
                raise StoreError(self.runs, exc, "create") from exc
        self._clean_leftovers()

    def _entry_mode(self) -> int:
        """Permissions of a new entry: rw for the owner, r for group and others where ``runs`` grants r."""
        try:
            return 0o600 | (stat.S_IMODE(self.runs.stat().st_mode) & 0o044)
        except OSError:
            return 0o600

    def _clean_leftovers(self) -> None:
        """Remove temporary files of killed writers and claims of processes that are gone."""
        now = time.time()
        try:
            entries = list(os.scandir(self.runs))
        except OSError:
            return
        stale_claims = []
        for entry in entries:
            name = entry.name
            try:
                if name.startswith(".") and name.endswith(".tmp") and entry.is_file(follow_symlinks=False):
                    if _stale_tmp(name, entry.stat(follow_symlinks=False).st_mtime, now):
                        os.unlink(entry.path)
                        log.info("results store: removed %s, left by a writer that is gone", entry.path)
                elif _is_claim_name(name):
                    stale_claims.append(Path(entry.path))
                elif name.startswith(".owner~") and name.endswith(".lock") and _lock_is_free(Path(entry.path)):
                    parts = name[len(".owner~"):-len(".lock")]
                    if _is_own_temporary(parts, "~") is not None:
                        os.unlink(entry.path)
            except OSError:
                continue  # gone meanwhile, or a store we may only read
        if stale_claims:
            with contextlib.suppress(OSError):
                with self._claims_lock():
                    for path in stale_claims:
                        stale, why = _claim_verdict(path)
                        if stale:
                            with contextlib.suppress(OSError):
                                path.unlink()
                                if why:
                                    _warn(f"results store: {path} {why}; removed")

    # -- keys and paths -------------------------------------------------------------------------
    @staticmethod
    def key(config: TrackingConfig) -> str:
        text = json.dumps({"config": config.key, "source": source_hash()}, sort_keys=True)
        return hashlib.sha256(text.encode()).hexdigest()[:24]

    def paths(self, config: TrackingConfig) -> tuple[Path, Path]:
        key = self.key(config)
        return self.runs / f"{key}.parquet", self.runs / f"{key}.json"

    def __contains__(self, config: TrackingConfig) -> bool:
        table, sidecar = self.paths(config)
        return table.is_file() and sidecar.is_file()

    # -- reading --------------------------------------------------------------------------------
    def load(self, config: TrackingConfig) -> TrackingResult | None:
        """The stored result of ``config``, or None: missing or incomplete (silently), or failing a
        check (then moved aside to ``NAME.corrupt`` with a warning naming the file and why)."""
        if not self.read:
            return None
        result, problem = self._read(config)
        if problem is None:
            return result
        # Move it aside only while holding the run's claim, after reading it again: another
        # process may be writing this very entry (its table replaced, its sidecar not yet).
        held = self.holds(config)  # run() claims a run before it looks again
        try:
            claimed = True if held else self.claim(config)
        except StoreError:
            claimed = None  # a store we may only read: nobody writes here, and nothing can be moved
        if claimed is False:
            log.info("results store: %s %s, but another process holds its claim; leaving it to that process",
                     *problem)
            return None
        try:
            result, problem = self._read(config)
            if problem is not None:
                self._move_aside(self.paths(config), *problem)
            return result
        finally:
            if claimed and not held:
                self.release(config)

    def _read(self, config: TrackingConfig):
        """``(result, None)``, ``(None, None)`` when absent or incomplete, or ``(None, (path, why))``."""
        table, sidecar = self.paths(config)
        try:
            text = sidecar.read_bytes()
        except FileNotFoundError:
            return None, None
        except OSError as exc:
            return None, (sidecar, f"cannot be read ({exc.strerror or exc})")
        try:
            meta = json.loads(text)
        except ValueError as exc:  # UnicodeDecodeError included
            return None, (sidecar, f"is not JSON ({exc})")
        if not isinstance(meta, dict) or meta.get("format") != STORE_FORMAT:
            found = meta.get("format") if isinstance(meta, dict) else type(meta).__name__
            return None, (sidecar, f"is not a results-store sidecar of format {STORE_FORMAT} (found {found!r})")
        unsealed = _seal_problem(meta)  # every field it serves (timing too) is under its digest
        if unsealed is not None:
            return None, (sidecar, unsealed)
        if meta.get("source_hash") != source_hash() or meta.get("config") != json.loads(json.dumps(config.to_dict())):
            return None, (sidecar, "describes another config or another package source")
        digest = meta.get("table_sha256")
        if not isinstance(digest, str) or len(digest) != 64:
            return None, (sidecar, "records no table digest")
        try:
            data = table.read_bytes()
        except FileNotFoundError:
            return None, (table, "is missing (its sidecar is there)")
        except OSError as exc:
            return None, (table, f"cannot be read ({exc.strerror or exc})")
        if hashlib.sha256(data).hexdigest() != digest:
            return None, (table, "does not match the SHA-256 its sidecar records (damaged, or another run's table)")
        try:
            frames = _parse_table(data)
        except Exception as exc:  # noqa: BLE001 - any parse failure means the same: not served
            return None, (table, f"cannot be parsed ({type(exc).__name__}: {exc})")
        try:
            check_frames(frames, config)
            if len(frames) != meta.get("frames"):
                raise ValueError(f"it holds {len(frames)} frames, its sidecar says {meta.get('frames')!r}")
        except ValueError as exc:
            return None, (table, f"does not fit its config: {exc}")
        timing = meta.get("timing")
        timing = dict(timing) if isinstance(timing, dict) else {}
        return TrackingResult(config=config, frames=frames, timing=timing), None

    def _move_aside(self, paths, bad: Path, why: str, then: str = "the run is recomputed") -> None:
        """Rename each of ``paths`` that exists to ``NAME.corrupt`` and warn, naming ``bad`` and ``why``."""
        moved, failed = [], []
        for path in paths:
            if not os.path.lexists(path):
                continue
            aside = path.with_name(path.name + ".corrupt")
            try:
                _remove(aside)  # an earlier quarantine of the same entry
                os.rename(path, aside)
                moved.append(str(aside))
            except OSError as exc:
                failed.append(f"{path} ({exc.strerror or exc})")
        where = f"moved aside to {' and '.join(moved)}" if moved else "left in place"
        if failed:
            where += f"; could not move {', '.join(failed)}"
        message = f"results store: {bad} {why}; {where}; {then}"
        if log.hasHandlers():  # e.g. the command line's run log (else logging would print it a second time)
            log.warning(message)
        warnings.warn(message, RuntimeWarning, stacklevel=3)

    # -- writing --------------------------------------------------------------------------------
    def save(self, result: TrackingResult) -> None:
        """Store ``result`` atomically (table first, sidecar last).

        Raises
        ------
        ValueError
            The frame table does not fit the config (:func:`check_frames`): nothing is written.
        StoreError
            A file cannot be written (read-only folder, disk full, ...).
        """
        from . import __version__

        check_frames(result.frames, result.config)
        table, sidecar = self.paths(result.config)
        data = _table_bytes(result.frames)
        meta = {
            "format": STORE_FORMAT,
            "config": result.config.to_dict(),
            "label": result.config.label,
            "seed": result.config.seed,
            "frames": len(result.frames),
            "table_sha256": hashlib.sha256(data).hexdigest(),
            "package_version": __version__,
            "source_hash": source_hash(),
            "timing": result.timing,
            "written": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        }
        meta = json.loads(json.dumps(meta))  # as a reader parses it (tuples become lists), then sealed
        meta["sidecar_digest"] = _seal(meta, _store_key())
        mode = self._entry_mode()
        for path, content in ((table, data), (sidecar, json.dumps(meta, indent=1, sort_keys=True).encode())):
            if path.is_dir() and not path.is_symlink():
                self._move_aside([path], path, "is a folder where a file should be")
            try:
                _atomic_write(path, content, mode)
            except OSError as exc:
                raise StoreError(path, exc) from exc

    # -- claims ---------------------------------------------------------------------------------
    def _claim_path(self, key: str) -> Path:
        return self.runs / f"{key}.claim"

    def _claims_lock(self):
        """An exclusive ``flock`` on the ``runs`` folder: taking over or releasing a claim is one step."""
        return _folder_lock(self.runs)

    def claim(self, config: TrackingConfig) -> bool:
        """Claim the run of ``config`` for this process: True when it is this store object's (now or
        already), False while another live process holds it. A stale claim is taken over.

        Raises
        ------
        StoreError
            The claim file cannot be created (a store that cannot be written).
        """
        key = self.key(config)
        with self._claims_guard:
            if key in self._claims:
                return True
        path = self._claim_path(key)
        token = secrets.token_hex(8)
        try:
            lock = self._owner_lock()
        except OSError as exc:
            raise StoreError(self.runs, exc) from exc
        record = json.dumps({"host": _HOST, "boot": _BOOT_ID, "pid": os.getpid(), "start": _start_ticks(os.getpid()),
                             "exe": _executable(os.getpid()), "lock": lock, "token": token}).encode()
        for attempt in range(2):
            try:
                created = self._create_claim(path, record)
            except OSError as exc:
                raise StoreError(path, exc) from exc
            if not created:
                if attempt == 1 or not self._take_over_if_stale(path):
                    self._drop_owner_lock()  # nothing claimed: no lock held for nothing
                    return False
                continue
            with self._claims_guard:
                self._claims[key] = (path, token)
                if self._heartbeat is None:
                    self._heartbeat = threading.Thread(target=self._refresh_claims, name="gimbal-lab store claims",
                                                       daemon=True)
                    self._heartbeat.start()
            return True
        return False

    def _owner_lock(self) -> str:
        """The name of the lock file this object holds (an exclusive ``flock``) while it claims runs,
        made the first time: ``runs/.owner~HOST~PID~RANDOM~CHECK.lock``. Locked under a temporary
        name, then renamed, so no cleaner ever finds it unlocked."""
        with self._claims_guard:
            if self._owner is not None:
                return self._owner[1]
            import fcntl

            name = f".owner~{_unique_tag('~')}.lock"
            tmp = _tmp_name(self.runs / "owner.lock")
            fd = os.open(tmp, os.O_RDWR | os.O_CREAT | os.O_EXCL, 0o644)
            try:
                os.fchmod(fd, 0o644)  # others on the store must be able to open it to test the lock
                fcntl.flock(fd, fcntl.LOCK_EX)
                os.rename(tmp, self.runs / name)
            except BaseException:
                os.close(fd)
                with contextlib.suppress(OSError):
                    os.unlink(tmp)
                raise
            self._owner = (fd, name)
            return name

    def _drop_owner_lock(self) -> None:
        """Remove and unlock this object's lock file once it holds no claim."""
        with self._claims_guard:
            if self._owner is None or self._claims:
                return
            fd, name = self._owner
            self._owner = None
        with contextlib.suppress(OSError):
            os.unlink(self.runs / name)
        os.close(fd)

    def _create_claim(self, path: Path, record: bytes) -> bool:
        """Make the claim file ``path`` holding ``record``, whole, unless it exists (then False):
        written under a temporary name, then hard-linked into place (``link`` fails on an existing
        name, as O_EXCL does); where links are not allowed, created with O_EXCL and written."""
        tmp = _tmp_name(path)
        try:
            _atomic_write(tmp, record, self._entry_mode())
            try:
                os.link(tmp, path)
                return True
            except FileExistsError:
                return False
            except OSError as exc:
                if exc.errno not in (errno.EPERM, errno.EOPNOTSUPP, errno.EMLINK, errno.ENOSYS):
                    raise
        finally:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(tmp)
        try:
            fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
        except FileExistsError:
            return False
        try:
            os.fchmod(fd, self._entry_mode())
            os.write(fd, record)
        finally:
            os.close(fd)
        return True

    def _take_over_if_stale(self, path: Path) -> bool:
        """Remove the claim at ``path`` if it is stale; True if it is gone (removed or released)."""
        try:
            with self._claims_lock():
                stale, why = _claim_verdict(path)
                if not stale:
                    return False
                with contextlib.suppress(FileNotFoundError):
                    path.unlink()
                if why:
                    _warn(f"results store: {path} {why}; taken over")
                else:
                    log.info("results store: took over %s, whose owner is gone", path)
                return True
        except OSError as exc:
            raise StoreError(path, exc) from exc

    def holds(self, config: TrackingConfig) -> bool:
        """Does this store object hold the claim of ``config``?"""
        with self._claims_guard:
            return self.key(config) in self._claims

    def release(self, config: TrackingConfig) -> None:
        """Give up this object's claim on ``config`` (nothing if it holds none)."""
        with self._claims_guard:
            held = self._claims.pop(self.key(config), None)
        if held is not None:
            self._release(*held)
        self._drop_owner_lock()

    def release_all(self) -> None:
        """Give up every claim this object holds."""
        with self._claims_guard:
            held, self._claims = list(self._claims.values()), {}
        for path, token in held:
            self._release(path, token)
        self._drop_owner_lock()

    def _release(self, path: Path, token: str) -> None:
        try:
            with self._claims_lock():
                if _read_claim(path).get("token") == token:  # not taken over meanwhile
                    path.unlink()
        except OSError as exc:
            log.warning("results store: could not remove the claim %s (%s)", path, exc)

    def _refresh_claims(self) -> None:
        """Heartbeat thread: touch every held claim each CLAIM_REFRESH_S; end when none is held."""
        while True:
            time.sleep(CLAIM_REFRESH_S)
            with self._claims_guard:
                held = list(self._claims.values())
                if not held:
                    self._heartbeat = None
                    return
            for path, _ in held:
                with contextlib.suppress(OSError):
                    os.utime(path)


def _read_claim(path: Path) -> dict:
    try:
        owner = json.loads(path.read_bytes())
    except (OSError, ValueError):
        return {}
    return owner if isinstance(owner, dict) else {}


def _is_claim_name(name: str) -> bool:
    """Is ``name`` a claim file's name, ``<key>.claim`` with the 24 hex digits of a store key?"""
    key, dot, suffix = name.partition(".")
    return suffix == "claim" and len(key) == 24 and all(ch in "0123456789abcdef" for ch in key)


def _executable(pid: int) -> str | None:
    """The executable process ``pid`` runs (Linux /proc), or None where it cannot be read."""
    try:
        return os.readlink(f"/proc/{pid}/exe")
    except OSError:
        return None


def _claim_problem(owner) -> str | None:
    """Why a parsed claim is not one the lab writes, or None."""
    if not isinstance(owner, dict):
        return f"holds {type(owner).__name__}, not a claim's fields"
    fields = {"host": str, "boot": str, "pid": int, "token": str}
    for name, kind in fields.items():
        value = owner.get(name)
        if not isinstance(value, kind) or isinstance(value, bool):
            return f"has no valid {name!r}"
    if owner["pid"] <= 0:
        return "names no process (pid <= 0)"
    if owner.get("start") is not None and (not isinstance(owner["start"], int) or isinstance(owner["start"], bool)):
        return "has no valid 'start'"
    return None


def _claim_verdict(path: Path) -> tuple[bool, str | None]:
    """Is the claim at ``path`` one nobody holds any more (see :class:`ResultsStore`, Notes)?

    Returns ``(stale, why)``: ``why`` says what is wrong with a claim that is not a gimbal-lab
    run's (taken over with a warning), None for one whose owner is merely gone, or a live one."""
    try:
        age_s = time.time() - path.stat().st_mtime
        text = path.read_bytes()
    except FileNotFoundError:
        return True, None
    if age_s > CLAIM_STALE_S:
        return True, None
    try:
        owner = json.loads(text)
    except ValueError:
        return True, "is not a claim gimbal-lab wrote (not JSON)"
    problem = _claim_problem(owner)
    if problem is not None:
        return True, f"is not a claim gimbal-lab wrote ({problem})"
    if owner["host"] != _HOST:
        return False, None
    if owner["boot"] != _BOOT_ID:
        return True, None  # this machine restarted since
    if not _alive(owner["pid"], owner.get("start")):
        return True, None
    lock = owner.get("lock")
    if isinstance(lock, str) and lock.startswith(".owner~") and "/" not in lock and not _lock_is_free(path.parent / lock):
        return False, None  # its owner holds its lock: a gimbal-lab run, alive
    running = _executable(owner["pid"]) or "its executable cannot be read"
    return True, f"names process {owner['pid']} ({running}), which is not a gimbal-lab run (it holds no store lock)"


def _lock_is_free(path: Path) -> bool:
    """Can an owner's lock file be locked (nobody holds it), or is it gone? False while a process
    holds it (or where the file system cannot lock: then it is taken as held)."""
    import fcntl

    try:
        fd = os.open(path, os.O_RDONLY)
    except FileNotFoundError:
        return True
    except OSError:
        return False
    try:
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
    except BlockingIOError:
        return False
    except OSError:
        return False
    finally:
        os.close(fd)
    return True


def _claim_is_stale(path: Path) -> bool:
    """Is the claim at ``path`` one nobody holds any more (see :func:`_claim_verdict`)?"""
    return _claim_verdict(path)[0]


def _warn(message: str) -> None:
    """A warning on :mod:`warnings` and, when it has handlers (the command line's run log), the log."""
    if log.hasHandlers():
        log.warning(message)
    warnings.warn(message, RuntimeWarning, stacklevel=3)


# ----------------------------------------------------------------------------------------------
# where the store is, and how many local workers a sweep starts
# ----------------------------------------------------------------------------------------------
#: Environment variable naming the results store that notebooks and commands use by default.
STORE_ENV = "GIMBAL_LAB_STORE"
#: Environment variable giving the number of local worker processes of a sweep that names none.
JOBS_ENV = "GIMBAL_LAB_JOBS"
#: The distribution name in the checkout's ``pyproject.toml``.
_PROJECT_NAME = "gimbal-lab"


def checkout_root() -> Path | None:
    """The source checkout this package is imported from, when the current folder lies inside it.

    The package's parent folder is a checkout when it holds the project's ``pyproject.toml`` (an
    editable install, ``pip install -e .``, imports the package from there). None for an installed
    copy of the package, or when the current folder is outside the checkout.
    """
    import tomllib

    root = Path(__file__).resolve().parent.parent
    try:
        name = tomllib.loads((root / "pyproject.toml").read_text()).get("project", {}).get("name")
        here = Path.cwd().resolve()
    except (OSError, ValueError):  # no pyproject.toml, an unreadable one, a current folder deleted
        return None
    if name != _PROJECT_NAME:
        return None
    return root if here == root or root in here.parents else None


def default_store_root() -> Path:
    """The results store used when none is given, as an absolute path: one rule for the notebooks
    and ``gimbal-lab run`` (whose ``--store DIR`` comes first), whatever the output folder.

    1. ``$GIMBAL_LAB_STORE`` when set and not blank (``~`` expanded; a relative path is taken from
       the current folder, which for a notebook is ``notebooks/``: give an absolute one);
    2. else ``results/store`` at the checkout's root (:func:`checkout_root`) when the current
       folder is inside the checkout: the notebooks and every ``gimbal-lab run`` there share one
       store;
    3. else ``store`` in the user's cache folder (platformdirs' ``user_cache_dir("gimbal-lab")``:
       ``$XDG_CACHE_HOME/gimbal-lab/store``, by default ``~/.cache/gimbal-lab/store``, on Linux).
    """
    text = os.environ.get(STORE_ENV, "")
    if text.strip():
        return Path(text).expanduser().absolute()
    root = checkout_root()
    if root is not None:
        return root / "results" / "store"
    from platformdirs import user_cache_dir

    return Path(user_cache_dir("gimbal-lab")).absolute() / "store"


def default_jobs() -> int:
    """Local worker processes of a sweep that names none: ``$GIMBAL_LAB_JOBS`` when set, else the
    CPU count.

    The test suite sets ``GIMBAL_LAB_JOBS`` in each pytest-xdist worker to its share of the CPUs,
    so notebooks running side by side do not start a pool of every CPU each.

    Raises
    ------
    ValueError
        ``$GIMBAL_LAB_JOBS`` is set but is not an integer >= 1 (the message names the variable).
    """
    text = os.environ.get(JOBS_ENV, "").strip()
    if not text:
        return os.cpu_count() or 1
    try:
        jobs = int(text)
    except ValueError:
        jobs = 0
    if jobs < 1:
        raise ValueError(f"{JOBS_ENV} must be an integer >= 1 (local worker processes), got {text!r}")
    return jobs


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


def _run_one(config: TrackingConfig, source: str | None = None) -> TrackingResult:
    """What a worker does for one config (module-level so any executor can pickle it). ``source``:
    the submitting process's :func:`source_hash`, which the worker's own must equal (a cluster's
    machines with another gimbal-lab would otherwise fill the store with results under a key that
    says they came from this code)."""
    _prepare_process()
    if source is not None and source != source_hash():
        raise SourceMismatch(
            f"a worker (pid {os.getpid()}) runs gimbal_lab source {source_hash()[:12]}, the sweep's is "
            f"{source[:12]}: install the same gimbal-lab on every worker (pip install of the same checkout)",
            source_hash(), source)
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
    """Cancel queued work and end the local workers now (they may be mid-render), then wait for
    the pool's manager thread to end.

    Not waiting for that thread leaves a race at interpreter exit (seen once on CPython 3.11):
    the exit hook of ``concurrent.futures`` writes to the thread's wake-up pipe without a lock
    while the thread, seeing its workers gone, closes that pipe; Python then prints "Exception
    ignored … OSError: [Errno 9] Bad file descriptor" after the command's own last line."""
    processes = list(getattr(pool, "_processes", {}).values())
    manager = getattr(pool, "_executor_manager_thread", None)
    pool.shutdown(wait=False, cancel_futures=True)
    for p in processes:
        if p.is_alive():
            p.terminate()
    for p in processes:
        p.join(timeout=5)
    if manager is not None and manager is not threading.current_thread():
        manager.join(timeout=5)


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
        Where finished runs are kept and looked up (None: nothing is stored). Runs another process
        has claimed in the same store are waited for, not computed again (see :class:`ResultsStore`).
    executor : concurrent.futures.Executor, optional
        Where runs go (e.g. :func:`dask_executor`). Default: a local pool of ``jobs`` spawned
        worker processes, or this process when ``jobs == 1`` (which then holds a GL context and
        must not fork afterwards).
    jobs : int, optional
        Local worker processes, >= 1 (default: :func:`default_jobs`, ``$GIMBAL_LAB_JOBS`` or the
        CPU count; at most the number of runs).
    progress : bool
        One bar over all frames to compute, with frames/s and the time left.

    Raises
    ------
    RunInterrupted
        On Ctrl-C, after stopping the workers; every run finished so far is in the store.
    SweepFailed
        :class:`WorkersDied`, :class:`SourceMismatch` or :class:`ResultMismatch`, after stopping
        the workers; the message says how many runs are kept and how to resume.
    StoreError
        The store cannot be written (checked before anything is computed).
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
        jobs = default_jobs()
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
    done = 0
    saving = None  # the run being stored: Ctrl-C may land after its files are written, before it is counted

    def count(config, result):
        nonlocal done
        done += 1
        if bar is not None:
            bar.update(len(result.frames))
            bar.set_postfix_str(f"{done}/{len(todo)} runs")

    def finish(config, result):
        nonlocal saving
        _check_result(config, result)
        saving = config
        if store is not None:
            store.save(result)
            store.release(config)
        unique[config] = result  # only now: a run counts as kept once it is stored
        saving = None
        seconds = result.timing.get("total_s", float("nan"))
        log.info("%s seed %d: %d frames in %.1f s", config.label, config.seed, len(result.frames), seconds)
        count(config, result)

    def take_over(waiting, first_only=False):
        """Claim the runs of ``waiting`` that no other process holds (any more): each is loaded
        from the store if it landed meanwhile (counted here), or returned to be computed (with
        ``first_only``, the first such one); the rest stay in ``waiting``."""
        ours = []
        for c in list(waiting):
            if not store.claim(c):
                continue
            waiting.remove(c)
            result = store.load(c)
            if result is None:
                ours.append(c)
                if first_only:
                    break
            else:
                store.release(c)
                unique[c] = result
                count(c, result)
        return ours

    pool = None
    futures: dict = {}
    # Workers spawn while this block submits; they inherit its environment (CHILD_THREAD_LIMITS).
    with _single_threaded_children() if executor is None else contextlib.nullcontext():
        try:
            # Claim before computing: runs another process holds are waited for, not computed
            # twice; a store that cannot be written fails here, before any work. This process
            # claims one run at a time (two such sweeps share the work); a pool, all it queues.
            in_process = executor is None and (jobs == 1 or len(todo) <= 1)
            waiting: list[TrackingConfig] = []
            mine = todo
            if store is not None and todo:
                if store.read:
                    waiting, mine = list(todo), []
                    mine = take_over(waiting, first_only=in_process)
                else:  # recompute everything, as asked, whoever else is computing it
                    for c in todo:
                        store.claim(c)
            if progress and todo:
                from tqdm.auto import tqdm

                bar = tqdm(total=sum(c.n_frames for c in todo), desc=desc, unit="frame", dynamic_ncols=True)
                bar.update(sum(len(unique[c].frames) for c in todo if unique[c] is not None))
            if in_process:
                while mine or waiting:
                    for c in mine:
                        finish(c, _run_one(c))
                    mine = take_over(waiting, first_only=True) if waiting else []
                    if waiting and not mine:
                        time.sleep(CLAIM_POLL_S)
            elif todo:
                restarts = 0
                pending: set = set()

                def submit(batch):
                    nonlocal pool
                    if batch and pool is None:
                        pool = executor if executor is not None else _local_pool(min(jobs, len(todo)))
                    for c in batch:
                        fut = pool.submit(_run_one, c, source_hash())
                        futures[fut] = c
                        pending.add(fut)

                submit(mine)
                while pending or waiting:
                    if pending:
                        finished, pending = wait(pending, timeout=CLAIM_POLL_S if waiting else None,
                                                 return_when=FIRST_COMPLETED)
                    else:
                        finished = set()
                        time.sleep(CLAIM_POLL_S)
                    broken = [fut for fut in finished if isinstance(fut.exception(), BrokenProcessPool)]
                    for fut in finished:
                        if fut not in broken:
                            finish(futures[fut], fut.result())
                    if broken:
                        # A local worker died: every queued run of that pool fails with it. The runs
                        # are deterministic, so a new pool computes exactly what the dead one would have.
                        if executor is not None or restarts >= MAX_POOL_RESTARTS:
                            raise WorkersDied(
                                f"worker processes died {restarts + 1} time(s) in this sweep (last: "
                                f"{broken[0].exception()}); "
                                + (f"the runner gives up after {MAX_POOL_RESTARTS} new pools of workers"
                                   if executor is None else "the executor it was given cannot be restarted"))
                        restarts += 1
                        _stop_pool(pool)
                        futures.clear()
                        unfinished = [c for c in todo if unique[c] is None and c not in waiting]
                        warnings.warn(f"a worker process died ({broken[0].exception()}); starting new workers for "
                                      f"the {len(unfinished)} unfinished run(s), {MAX_POOL_RESTARTS - restarts} "
                                      "restart(s) left", RuntimeWarning, stacklevel=2)
                        pool, pending = None, set()
                        submit(unfinished)
                    if waiting:
                        submit(take_over(waiting))
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
            if isinstance(exc, SweepFailed) and exc.kept is None:
                kept = sum(r is not None for r in unique.values())
                raise exc._stopped(kept, len(unique), store, _failure_message(exc, kept, len(unique), store))
            raise
        finally:
            if store is not None:
                store.release_all()
            if pool is not None and executor is None:
                pool.shutdown(wait=True)
            if bar is not None:
                bar.close()
    return [unique[c] for c in configs]


def _failure_message(exc: SweepFailed, kept: int, total: int, store) -> str:
    """``exc``'s message, with what is kept and how to resume."""
    if isinstance(exc, SourceMismatch) and exc.sweep_source and exc.worker_source:
        now = _hash_package()
        if now != exc.sweep_source and now == exc.worker_source:
            # The package's files were edited while the sweep ran: the workers started later read the edit.
            where = "" if store is None else f" and kept in {store.root} under the source the sweep started with"
            return (f"gimbal_lab's files changed during the sweep (now source {now[:12]}, the sweep's "
                    f"{exc.sweep_source[:12]}; a file edited while it ran?): {kept} of {total} runs are "
                    f"finished{where}; run the same command again: it computes every run with the code as it is now "
                    "(the kept runs are reused only if the sweep's source is restored)")
    return f"{exc.args[0]}; {_resume_hint(kept, total, store)}"


if sys.platform == "win32":  # pragma: no cover - the lab targets Linux servers
    warnings.warn("gimbal_lab.runner is tested on Linux only", RuntimeWarning)
