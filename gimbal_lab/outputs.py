"""Output files and folders: every file whole or absent, and only the lab's own files replaced.

* :func:`atomic_path` yields a temporary name beside a file (same folder, same suffix, unique to
  the process and the call); on success it is renamed over the file, on any error (Ctrl-C
  included) it is removed and the file is left as it was. ``show``, ``calibrate`` and ``track``
  write through it.
* :class:`ReportFolder` is a folder a study's report is written into (``OUT/STUDY``). It keeps a
  manifest of the files the lab wrote there (:data:`MANIFEST`) and refuses, before any work, a
  folder that holds a file the manifest does not list. A report is written into a hidden staging
  folder inside it, then each file is renamed into place: only the files the report writes are
  replaced, nothing else is deleted, and a report interrupted before that step changes nothing.
  Files of an earlier report that this one does not write again (the clips after ``--no-clips``)
  are kept and listed in :attr:`ReportFolder.kept`.
* :func:`check_writable_folder` and :func:`check_new_file` validate an output path before any
  work, each failure an :class:`OutputError` naming the path in one line.

Leftovers of a process killed while writing (temporary files, staging folders) carry its pid and
are removed by the next writer once that process is gone.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import re
import secrets
import shutil
import signal
import socket
import threading
import time
from pathlib import Path

__all__ = ["OutputError", "ReportInterrupted", "atomic_path", "temporary_name", "remove_leftovers", "check_writable_folder", "check_new_file", "ReportFolder", "MANIFEST",
           "deferred_interrupts", "folder_lock"]

#: The manifest of a report folder: the files the lab wrote there, with size and SHA-256.
MANIFEST = ".gimbal-lab-manifest.json"
_STAGING = ".gimbal-lab-staging-"
_PARTIAL = ".partial-"
_HOST = re.sub(r"[^A-Za-z0-9_]", "_", socket.gethostname())


class OutputError(ValueError):
    """An output path cannot be used; ``str()`` is one line naming the path and what to do."""

    def __init__(self, message: str, path=None):
        super().__init__(message)
        self.path = None if path is None else Path(path)


class ReportInterrupted(KeyboardInterrupt):
    """Ctrl-C while a report was written; ``str()`` says whether its folder is unchanged or whole."""

    def __str__(self) -> str:
        return str(self.args[0]) if self.args else "interrupted"


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _owner_gone(name: str) -> bool:
    """Is the temporary file or folder ``name`` (``...-HOST-PID-RANDOM...``) a leftover of a dead
    process of this machine?"""
    core = name.split(_PARTIAL, 1)[-1] if _PARTIAL in name else name[len(_STAGING):]
    parts = core.split(".", 1)[0].split("-")
    return len(parts) >= 3 and parts[0] == _HOST and parts[1].isdigit() and not _alive(int(parts[1]))


def _unique() -> str:
    return f"{_HOST}-{os.getpid()}-{secrets.token_hex(4)}"


def _is_ours_in_progress(name: str) -> bool:
    return name.startswith(_STAGING) or (name.startswith(".") and _PARTIAL in name)


def remove_leftovers(folder: Path) -> None:
    """Remove temporary files and staging folders of dead writers directly in ``folder``."""
    with contextlib.suppress(OSError):
        for entry in os.scandir(folder):
            if _is_ours_in_progress(entry.name) and _owner_gone(entry.name):
                if entry.is_dir(follow_symlinks=False):
                    shutil.rmtree(entry.path, ignore_errors=True)
                else:
                    with contextlib.suppress(OSError):
                        os.unlink(entry.path)


@contextlib.contextmanager
def deferred_interrupts():
    """Hold SIGINT back until the block ends: a Ctrl-C that arrives inside it lands after it.

    Python runs signal handlers in the main thread whichever thread the kernel delivered the signal
    to, so the block swaps the main thread's SIGINT handler for one that only notes the signal, and
    calls the previous handler (``KeyboardInterrupt`` by default) once the block is done. Blocking
    the signal with ``pthread_sigmask`` would not do: the mask is per thread, and any other thread
    of the process (a progress bar's monitor, the store's claim refresher) would take the signal.
    Outside the main thread, where handlers cannot be set, the block runs unguarded.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    caught = []

    def note(signum, frame):
        caught.append(frame)

    previous = signal.signal(signal.SIGINT, note)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
        if caught:
            if callable(previous):
                previous(signal.SIGINT, caught[0])
            elif previous == signal.SIG_DFL:
                raise KeyboardInterrupt


# ----------------------------------------------------------------------------------------------
# checking an output path before any work
# ----------------------------------------------------------------------------------------------
def _can_write(folder: Path) -> bool:
    effective = os.access in os.supports_effective_ids
    return os.access(folder, os.W_OK | os.X_OK, effective_ids=effective)


def _folder_problem(path: Path) -> tuple[Path, str] | None:
    """What keeps ``path`` from being a folder this process writes in (or creates): the culprit
    (``path`` or the deepest part of it that exists) and a reason, or None."""
    probe = Path(os.path.abspath(path))
    while not (probe.exists() or probe.is_symlink()) and probe.parent != probe:
        probe = probe.parent
    if not probe.is_dir():
        return probe, "a file, not a folder" if probe.is_file() else "a device or special file, not a folder"
    if not _can_write(probe):
        return probe, "not writable (permission denied or a read-only file system)"
    return None


def check_writable_folder(path, what: str = "output folder") -> Path:
    """Check that ``path`` is a folder this process can write in, or one it can create.

    Every part of ``path`` that exists must be a folder, and the deepest existing one must be
    writable. Nothing is created. Raises :class:`OutputError` naming ``what`` and the culprit.
    """
    path = Path(os.fspath(path))
    if not str(path).strip():
        raise OutputError(f"{what} must name a folder, got an empty string")
    problem = _folder_problem(path)
    if problem is None:
        return path
    culprit, reason = problem
    if culprit == Path(os.path.abspath(path)):
        raise OutputError(f"{what} {path} is {reason}", culprit)
    raise OutputError(f"{what} {path} cannot be made: {culprit} is {reason}", culprit)


def check_new_file(path, what: str = "output file", suffixes=None) -> Path:
    """Check that ``path`` can be written as a file: not a folder, its folder writable or creatable,
    and (with ``suffixes``) one of those suffixes. Nothing is created. Raises :class:`OutputError`."""
    path = Path(os.fspath(path))
    if not str(path).strip():
        raise OutputError(f"{what} must name a file, got an empty string")
    if suffixes is not None and path.suffix.lower() not in suffixes:
        raise OutputError(f"{what} {path} must end in {' or '.join(suffixes)}", path)
    if path.is_dir():
        raise OutputError(f"{what} {path} is a folder; give a file name", path)
    if path.exists() and not path.is_file():
        raise OutputError(f"{what} {path} is not a regular file; give a file name", path)
    problem = _folder_problem(path.parent)
    if problem is not None:
        culprit, reason = problem
        raise OutputError(f"{what} {path} cannot be written: {culprit} is {reason}", culprit)
    return path


# ----------------------------------------------------------------------------------------------
# one file
# ----------------------------------------------------------------------------------------------
def temporary_name(path: Path) -> Path:
    """A hidden name beside ``path`` with its suffix, unique to this process and call:
    ``.STEM.partial-HOST-PID-RANDOM.SUFFIX``."""
    return path.with_name(f".{path.stem}{_PARTIAL}{_unique()}{path.suffix}")


@contextlib.contextmanager
def atomic_path(path):
    """``with atomic_path(path) as tmp:`` write ``tmp``; on success it replaces ``path``.

    ``tmp`` lies in ``path``'s folder (created if needed) and ends in ``path``'s suffix (writers
    such as matplotlib and OpenCV pick the format from it). On any error, Ctrl-C included, ``tmp``
    is removed and ``path`` keeps its old content; a block that wrote nothing raises ValueError.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    remove_leftovers(path.parent)
    tmp = temporary_name(path)
    try:
        yield tmp
        if not tmp.exists():
            raise ValueError(f"nothing was written to {path}")
        os.replace(tmp, path)
    finally:
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()


# ----------------------------------------------------------------------------------------------
# a report folder
# ----------------------------------------------------------------------------------------------
def _sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def _files(root: Path) -> list[str]:
    """Every file (and link) under ``root``, as sorted POSIX paths relative to it, leaving out the
    manifest and anything a writer has in progress."""
    found = []
    for folder, dirs, files in os.walk(root):
        dirs[:] = sorted(d for d in dirs if not _is_ours_in_progress(d) or os.path.islink(os.path.join(folder, d)))
        rel = Path(folder).relative_to(root)
        for name in files + [d for d in dirs if os.path.islink(os.path.join(folder, d))]:
            if rel == Path(".") and name == MANIFEST:
                continue
            if _is_ours_in_progress(name):
                continue
            found.append((rel / name).as_posix())
    return sorted(found)


@contextlib.contextmanager
def folder_lock(folder: Path):
    """Hold an exclusive ``flock`` on ``folder`` (nothing where the file system cannot lock it)."""
    import fcntl

    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        yield
        return
    try:
        with contextlib.suppress(OSError):
            fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)


class ReportFolder:
    """A folder the lab writes a report into and keeps a manifest of (``OUT/STUDY``).

    Parameters
    ----------
    path : str or os.PathLike
        The folder. It may not exist yet (it is created, with its parents, when the report is
        written), may be empty, or may hold what an earlier report wrote there.
    what : str
        How error messages name the folder (e.g. ``"--out"``).

    Notes
    -----
    ``check()`` refuses (:class:`OutputError`, one line naming the folder and the first unknown
    file) a folder holding a file the manifest does not list; call it before any work.
    ``with folder.staging() as tmp:`` yields an empty hidden folder inside ``path``; when the
    block ends without error the folder is checked again, the manifest is written listing the
    old and the new files, every file of ``tmp`` is renamed into place (Ctrl-C held back
    meanwhile) and the manifest is written again with each new file's size and SHA-256. On an
    error, ``tmp`` is removed and ``path`` is as it was. Files the manifest lists that this
    report did not write are kept (:attr:`kept`); nothing else is ever deleted. Two reports
    committing to one folder at once take turns (an ``flock`` on the folder).
    """

    def __init__(self, path, what: str = "output folder"):
        path = os.fspath(path)
        if not isinstance(path, str) or not path.strip():
            raise OutputError(f"{what} must be a non-empty path, got {path!r}")
        self.path, self.what = Path(path), what
        self.written: list[Path] = []
        self.kept: list[Path] = []

    @property
    def manifest_path(self) -> Path:
        return self.path / MANIFEST

    def _manifest(self) -> dict:
        try:
            data = json.loads(self.manifest_path.read_text())
        except FileNotFoundError:
            return {}
        except (OSError, ValueError) as exc:
            raise OutputError(f"{self.what} {self.path}: its manifest {MANIFEST} cannot be read ({exc}); move the "
                              "folder away or give another one", self.manifest_path) from None
        if not isinstance(data, dict) or not isinstance(data.get("files", {}), dict):
            raise OutputError(f"{self.what} {self.path}: its manifest {MANIFEST} is not one gimbal-lab wrote; move "
                              "the folder away or give another one", self.manifest_path)
        return data

    def check(self) -> None:
        """Refuse a folder that cannot be written or holds files the lab did not write there."""
        check_writable_folder(self.path, self.what)
        if not self.path.is_dir():
            return
        remove_leftovers(self.path)
        known = set(self._manifest().get("files", {}))
        unknown = [name for name in _files(self.path) if name not in known]
        if unknown:
            more = f" (and {len(unknown) - 1} more)" if len(unknown) > 1 else ""
            raise OutputError(
                f"{self.what} {self.path} holds {unknown[0]}{more}, which gimbal-lab did not write: it writes only into "
                f"a new or empty folder or one it wrote before (listed in {MANIFEST}); move the file(s) away or give "
                "another folder", self.path / unknown[0])

    @contextlib.contextmanager
    def staging(self):
        """Yield an empty hidden folder inside :attr:`path`; commit its files on success (see Notes)."""
        self.check()
        created = not self.path.exists()
        try:
            self.path.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise OutputError(f"{self.what} {self.path} cannot be created: {exc.strerror or exc}", self.path) from None
        tmp = self.path / f"{_STAGING}{_unique()}"
        self.written, self.kept = [], []
        try:
            tmp.mkdir()
            yield tmp
            self._commit(tmp)
        except KeyboardInterrupt:
            if self.written:  # Ctrl-C was held back while the files were renamed; it lands after
                raise ReportInterrupted(f"interrupted after the report was written whole to {self.path}") from None
            raise ReportInterrupted(f"interrupted while writing the report: {self.path} is unchanged") from None
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
            if created:
                with contextlib.suppress(OSError):
                    self.path.rmdir()  # only if nothing was committed (an empty folder this call made)

    def _write_manifest(self, files: dict) -> None:
        data = {"format": 1, "written_by": "gimbal-lab",
                "note": "files gimbal-lab wrote in this folder; it refuses to write into a folder holding others",
                "files": dict(sorted(files.items()))}
        tmp = temporary_name(self.manifest_path)
        tmp.write_text(json.dumps(data, indent=1) + "\n")
        os.replace(tmp, self.manifest_path)

    def _commit(self, tmp: Path) -> None:
        new = _files(tmp)
        with folder_lock(self.path):
            self.check()  # a file may have appeared while the report was computed
            files = {name: entry for name, entry in self._manifest().get("files", {}).items()
                     if (self.path / name).exists()}
            stamp = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
            entries = {name: {"bytes": (tmp / name).stat().st_size, "sha256": _sha256(tmp / name),
                              "written_utc": stamp} for name in new}
            with deferred_interrupts():
                self._write_manifest({**files, **{name: {"pending": True} for name in new}})
                for name in new:
                    (self.path / name).parent.mkdir(parents=True, exist_ok=True)
                    os.replace(tmp / name, self.path / name)
                files.update(entries)
                self._write_manifest(files)
                # set before a held-back Ctrl-C lands, so that it is known the report is whole
                self.written = [self.path / name for name in new]
                self.kept = [self.path / name for name in files if name not in entries]
