"""Output files and folders: every file whole or absent, and only the lab's own files replaced.

* :func:`atomic_path` yields a temporary name beside a file (same folder, same suffix, unique to
  the process and the call); on success it is renamed over the file, on any error (Ctrl-C
  included) it is removed and the file is left as it was. ``show``, ``calibrate`` and ``track``
  write through it.
* :class:`ReportFolder` is a folder a study's report is written into (``OUT/STUDY``). It keeps a
  manifest of the files the lab wrote there (:data:`MANIFEST`) and refuses, before any work, a
  folder that holds a file the manifest does not list. A report is written into a hidden staging
  folder inside it, then committed as a unit: every file it replaces is first kept aside (a hard
  link, or a copy), then the new files are renamed into place; a failure at any step renames the
  kept files back, so the folder is either wholly the new report or byte for byte the old one
  (:class:`ReportNotWritten` says which, and what is left where it could not be put back). Only
  the files the report writes are replaced, nothing else is deleted. A lab file whose bytes no
  longer match the manifest (a hand edit) is refused before any work, unless the caller asks to
  overwrite edited files (:func:`overwriting_edited`, ``gimbal-lab run --overwrite-edited``).
  Files of an earlier report that this one does not write again (the clips after ``--no-clips``)
  are kept and listed in :attr:`ReportFolder.kept`.
* :func:`check_writable_folder` and :func:`check_new_file` validate an output path before any
  work, each failure an :class:`OutputError` naming the path in one line.

Leftovers of a process killed while writing (temporary files, staging folders) carry its pid and
a check tag computed from the rest of the name (:func:`is_own_temporary`); the next writer removes
them once that process is gone. A file or folder that only looks like one (a user's
``.notes.partial-x.txt``) fails the tag and is never touched.
"""

from __future__ import annotations

import contextlib
import contextvars
import errno
import hashlib
import json
import os
import re
import secrets
import shutil
import signal
import socket
import stat
import threading
import time
from pathlib import Path

__all__ = ["OutputError", "ReportInterrupted", "ReportNotWritten", "atomic_path", "temporary_name", "remove_leftovers",
           "check_writable_folder", "check_new_file", "ReportFolder", "MANIFEST", "deferred_interrupts", "folder_lock",
           "overwriting_edited", "unique_tag", "is_own_temporary"]

#: The manifest of a report folder: the files the lab wrote there, with size and SHA-256.
MANIFEST = ".gimbal-lab-manifest.json"
_STAGING = ".gimbal-lab-staging-"
_ASIDE_MARK = ".files-a-commit-replaces"  # inside a commit's aside folder (a staging folder has none)
_PARTIAL = ".partial-"
_HOST = re.sub(r"[^A-Za-z0-9_]", "_", socket.gethostname())


class OutputError(ValueError):
    """An output path cannot be used; ``str()`` is one line naming the path and what to do."""

    def __init__(self, message: str, path=None):
        super().__init__(message)
        self.path = None if path is None else Path(path)


class ReportNotWritten(RuntimeError):
    """A report could not be committed to its folder; ``str()`` is one line saying why and what
    state the folder is in (as before the run, or which files are new and where the old ones are).

    Attributes
    ----------
    unchanged : bool
        True when the folder is byte for byte as it was before the run.
    """

    def __init__(self, message: str, unchanged: bool):
        super().__init__(message)
        self.unchanged = unchanged


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


def _check_tag(core: str) -> str:
    """The check tag of a temporary name's ``HOST-PID-RANDOM`` part: 6 hex digits of its SHA-256
    under a fixed prefix. Not a secret: it tells the lab's own names from names that merely look
    alike (a user's file), which would need the tag computed on purpose."""
    return hashlib.sha256(f"gimbal-lab temporary {core}".encode()).hexdigest()[:6]


def unique_tag(sep: str = "-") -> str:
    """``HOST-PID-RANDOM-CHECK``: unique to this process and call, with its check tag (``sep``
    joins the parts; the results store uses ``~``)."""
    core = sep.join((_HOST, str(os.getpid()), secrets.token_hex(4)))
    return f"{core}{sep}{_check_tag(core)}"


def is_own_temporary(tag: str, sep: str = "-") -> tuple[str, int] | None:
    """``(host, pid)`` when ``tag`` (``HOST-PID-RANDOM-CHECK``) is one :func:`unique_tag` made,
    else None. The host may itself hold ``sep``; the last three parts are fixed."""
    core, _, check = tag.rpartition(sep)
    host, _, rest = core.rpartition(sep)
    host, _, pid = host.rpartition(sep)
    if not (host and pid.isdigit() and len(check) == 6) or check != _check_tag(core):
        return None
    return host, int(pid)


def _owner_gone(name: str) -> bool:
    """Is the temporary file or folder ``name`` (``...-HOST-PID-RANDOM-CHECK...``) a leftover of a
    dead process of this machine, and a name the lab made (its check tag fits)?"""
    core = name.split(_PARTIAL, 1)[-1] if _PARTIAL in name else name[len(_STAGING):]
    owner = is_own_temporary(core.split(".", 1)[0])
    return owner is not None and owner[0] == _HOST and not _alive(owner[1])


def _unique() -> str:
    return unique_tag()


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


_OVERWRITE_EDITED = contextvars.ContextVar("gimbal_lab_overwrite_edited", default=False)


@contextlib.contextmanager
def overwriting_edited(enabled: bool = True):
    """While the block runs, :class:`ReportFolder` objects made without ``overwrite_edited`` replace
    lab files that were edited since the lab wrote them instead of refusing the folder
    (``gimbal-lab run --overwrite-edited``; the studies' report code needs no argument for it)."""
    token = _OVERWRITE_EDITED.set(bool(enabled))
    try:
        yield
    finally:
        _OVERWRITE_EDITED.reset(token)


def _is_record_of(path: Path, entry) -> bool:
    """Does the regular file at ``path`` hold the bytes a manifest entry records (size, SHA-256)?"""
    if not isinstance(entry, dict) or not isinstance(entry.get("sha256"), str):
        return False
    try:
        st = os.lstat(path)
    except OSError:
        return False
    return stat.S_ISREG(st.st_mode) and st.st_size == entry.get("bytes") and _sha256(path) == entry["sha256"]


def _write_file(path: Path, data: bytes) -> None:
    """Write ``data`` to a new file ``path`` (the one place the commit writes bytes)."""
    with open(path, "xb") as handle:
        handle.write(data)


class ReportFolder:
    """A folder the lab writes a report into and keeps a manifest of (``OUT/STUDY``).

    Parameters
    ----------
    path : str or os.PathLike
        The folder. It may not exist yet (it is created, with its parents, when the report is
        written), may be empty, or may hold what an earlier report wrote there.
    what : str
        How error messages name the folder (e.g. ``"--out"``).
    overwrite_edited : bool or None
        Replace lab files whose bytes differ from the manifest's record (hand edits) instead of
        refusing the folder. None (default): as :func:`overwriting_edited` says (False outside it).

    Notes
    -----
    ``check()`` refuses (:class:`OutputError`, one line naming the folder and the first file) a
    folder holding a file the manifest does not list, or a listed file whose size or SHA-256 is
    not the manifest's (edited, replaced, or a folder in its place); call it before any work.
    ``with folder.staging() as tmp:`` yields an empty hidden folder inside ``path``; when the
    block ends without error the report is committed as a unit, under an ``flock`` on the folder
    (two reports committing at once take turns) and with Ctrl-C held back:

    1. the folder is checked again; every file the report replaces (and the manifest) is kept
       aside in a second hidden folder, as a hard link (a copy where links fail), and a file that
       cannot be replaced (a folder in its place) stops the commit here;
    2. the manifest is written listing the old files and the new ones (each new entry recording
       the bytes it replaces, so a commit cut short by a kill leaves a folder the next run takes);
    3. every file of ``tmp`` is renamed into place;
    4. the manifest is written again with each new file's size and SHA-256.

    A failure at any step (disk full, an immutable file, ...) undoes the steps done: new files
    are removed, the kept ones renamed back (renames need no space), folders it made removed,
    so the folder is byte for byte what it was, and :class:`ReportNotWritten` says so. If even
    that fails, the error names the files that are new and the folder holding the old ones. A
    commit whose process was killed (SIGKILL, a power cut) is undone the same way by the next
    ``check()``: its manifest still has pending entries, and its aside folder the old files.
    Files the manifest lists that this report did not write are kept (:attr:`kept`); nothing
    else is ever deleted.
    """

    def __init__(self, path, what: str = "output folder", *, overwrite_edited: bool | None = None):
        path = os.fspath(path)
        if not isinstance(path, str) or not path.strip():
            raise OutputError(f"{what} must be a non-empty path, got {path!r}")
        self.path, self.what = Path(path), what
        self.overwrite_edited = overwrite_edited
        self.written: list[Path] = []
        self.kept: list[Path] = []
        self._interrupted_state: str | None = None

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

    def _overwrites_edited(self) -> bool:
        return _OVERWRITE_EDITED.get() if self.overwrite_edited is None else bool(self.overwrite_edited)

    def edited(self) -> list[str]:
        """The files the manifest lists whose bytes are no longer the ones the lab wrote (sorted)."""
        found = []
        for name, entry in sorted(self._manifest().get("files", {}).items()):
            path = self.path / name
            if not os.path.lexists(path):
                continue  # deleted by hand: nothing to overwrite
            if not isinstance(entry, dict) or ("sha256" not in entry and entry.get("pending")):
                continue  # a commit of an older version cut short: its bytes were not recorded
            if not (_is_record_of(path, entry) or _is_record_of(path, entry.get("was"))):
                found.append(name)
        return found

    def check(self) -> None:
        """Refuse a folder that cannot be written, holds files the lab did not write there, or
        holds a lab file edited since (unless edited files are to be overwritten). A commit a
        killed process left half done is undone first."""
        self._check(recover=True)

    def _check(self, recover: bool) -> None:
        check_writable_folder(self.path, self.what)
        if not self.path.is_dir():
            return
        if recover:  # (the commit calls this under the folder's lock already, and recovers nothing)
            with folder_lock(self.path):
                self._recover()
        remove_leftovers(self.path)
        known = set(self._manifest().get("files", {}))
        unknown = [name for name in _files(self.path) if name not in known]
        if unknown:
            more = f" (and {len(unknown) - 1} more)" if len(unknown) > 1 else ""
            raise OutputError(
                f"{self.what} {self.path} holds {unknown[0]}{more}, which gimbal-lab did not write: it writes only into "
                f"a new or empty folder or one it wrote before (listed in {MANIFEST}); move the file(s) away or give "
                "another folder", self.path / unknown[0])
        if self._overwrites_edited():
            return
        edited = self.edited()
        if edited:
            more = f" (and {len(edited) - 1} more)" if len(edited) > 1 else ""
            raise OutputError(
                f"{self.what} {self.path}: {edited[0]}{more} was changed after gimbal-lab wrote it (its bytes differ "
                f"from the record in {MANIFEST}); move it away to keep it, or pass --overwrite-edited to replace it",
                self.path / edited[0])

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
        self.written, self.kept, self._interrupted_state = [], [], None
        try:
            tmp.mkdir()
            yield tmp
            self._commit(tmp)
        except KeyboardInterrupt:
            if self.written:  # Ctrl-C was held back while the files were renamed; it lands after
                raise ReportInterrupted(f"interrupted after the report was written whole to {self.path}") from None
            if self._interrupted_state:
                raise ReportInterrupted(f"interrupted while writing the report: {self._interrupted_state}") from None
            raise ReportInterrupted(f"interrupted while writing the report: {self.path} is unchanged") from None
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
            if created:
                with contextlib.suppress(OSError):
                    self.path.rmdir()  # only if nothing was committed (an empty folder this call made)

    def _recover(self) -> None:
        """Undo a commit its process was killed in (call under the folder's lock).

        A killed commit leaves its manifest with pending entries and the files it replaced in its
        aside folder (a leftover of a dead process): those are renamed back, the files it added
        removed and its manifest restored, so the folder is the earlier report again. An aside
        folder next to a manifest with nothing pending belongs to a commit that was done (or had
        not begun): it is only removed."""
        try:
            entries = list(os.scandir(self.path))
        except OSError:
            return
        for entry in entries:
            aside = Path(entry.path)
            if not (entry.name.startswith(_STAGING) and entry.is_dir(follow_symlinks=False)
                    and (aside / _ASIDE_MARK).exists() and _owner_gone(entry.name)):
                continue
            files = self._manifest().get("files", {})
            pending = {name: e for name, e in files.items() if isinstance(e, dict) and e.get("pending")}
            if pending:
                for name, e in pending.items():
                    path = self.path / name
                    if (aside / name).is_file():
                        os.replace(aside / name, path)
                    elif e.get("was") is None:  # a file the killed commit added (or was about to)
                        if _is_record_of(path, e):
                            os.unlink(path)
                        if path.parent != self.path:
                            with contextlib.suppress(OSError):
                                path.parent.rmdir()  # a folder it made, if nothing else is in it
                if (aside / MANIFEST).is_file():
                    os.replace(aside / MANIFEST, self.manifest_path)
                else:
                    os.unlink(self.manifest_path)  # the killed commit was the folder's first
            shutil.rmtree(aside, ignore_errors=True)

    def _write_manifest(self, files: dict) -> None:
        data = {"format": 1, "written_by": "gimbal-lab",
                "note": "files gimbal-lab wrote in this folder; it refuses to write into a folder holding others",
                "files": dict(sorted(files.items()))}
        tmp = temporary_name(self.manifest_path)
        try:
            _write_file(tmp, (json.dumps(data, indent=1) + "\n").encode())
            os.replace(tmp, self.manifest_path)
        finally:
            with contextlib.suppress(FileNotFoundError):
                tmp.unlink()

    def _commit(self, tmp: Path) -> None:
        new = _files(tmp)
        with folder_lock(self.path):
            self._check(recover=False)  # a file may have appeared, or been edited, meanwhile
            files = {name: entry for name, entry in self._manifest().get("files", {}).items()
                     if os.path.lexists(self.path / name)}
            stamp = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
            entries = {}
            for name in new:
                entry = {"bytes": (tmp / name).stat().st_size, "sha256": _sha256(tmp / name), "written_utc": stamp}
                old = files.get(name, {})
                if (old.get("bytes"), old.get("sha256")) == (entry["bytes"], entry["sha256"]) and "written_utc" in old:
                    entry["written_utc"] = old["written_utc"]  # the same bytes again: its record stays as it was
                entries[name] = entry
            aside = self.path / f"{_STAGING}{_unique()}"
            with deferred_interrupts():
                _Commit(self, tmp, aside, new).run(files, entries)
                # set before a held-back Ctrl-C lands, so that it is known the report is whole
                files.update(entries)
                self.written = [self.path / name for name in new]
                self.kept = [self.path / name for name in files if name not in entries]


class _Commit:
    """One report's commit into its folder, and its undoing (see :class:`ReportFolder`, Notes)."""

    def __init__(self, folder: ReportFolder, tmp: Path, aside: Path, new: list[str]):
        self.folder, self.tmp, self.aside, self.new = folder, tmp, aside, new
        self.root = folder.path
        self.kept_aside: set[str] = set()  # names (the manifest included) kept in ``aside``
        self.made: list[Path] = []  # folders made for new files, in the order made
        self.placed: list[str] = []  # names renamed into place
        self.manifest_touched = False

    def run(self, files: dict, entries: dict) -> None:
        step = "keeping the files it replaces aside"
        try:
            self._keep_aside()
            step = f"writing {MANIFEST}"
            self.manifest_touched = True
            self.folder._write_manifest({**files, **{name: {**entries[name], "pending": True, "was": files.get(name)}
                                                     for name in self.new}})
            for name in self.new:
                step = f"renaming {name} into place"
                target = self.root / name
                self._make_parents(target.parent)
                os.replace(self.tmp / name, target)
                self.placed.append(name)
            step = f"writing {MANIFEST}"
            self.folder._write_manifest({**files, **entries})
        except BaseException as exc:
            self._fail(step, exc)
        shutil.rmtree(self.aside, ignore_errors=True)

    def _keep_aside(self) -> None:
        """Step 1: hard-link (or copy) every file to be replaced into ``aside``; nothing visible changes."""
        self.aside.mkdir()
        (self.aside / _ASIDE_MARK).touch()
        for name in [*self.new, MANIFEST]:
            target = self.root / name
            if not os.path.lexists(target):
                continue
            if os.path.isdir(target) and not os.path.islink(target):
                raise IsADirectoryError(errno.EISDIR, "a folder is where the report's file goes", str(target))
            keep = self.aside / name
            if not keep.parent.is_dir():
                keep.parent.mkdir(parents=True)
            try:
                os.link(target, keep, follow_symlinks=False)
            except OSError:
                shutil.copy2(target, keep, follow_symlinks=False)
            self.kept_aside.add(name)

    def _make_parents(self, folder: Path) -> None:
        missing = []
        while not folder.is_dir():
            missing.append(folder)
            folder = folder.parent
        for path in reversed(missing):
            path.mkdir()
            self.made.append(path)

    def _fail(self, step: str, exc: BaseException):
        """Undo what was done, then raise :class:`ReportNotWritten` saying what state the folder is in."""
        if isinstance(exc, OSError) and exc.strerror:  # a rename names two paths; the step names the file
            why = exc.strerror + (f": {exc.filename}" if exc.filename and exc.filename2 is None else "")
        else:
            why = f"{type(exc).__name__}: {exc}"
        not_undone = []
        for name in reversed(self.placed):
            target = self.root / name
            try:
                if name in self.kept_aside:
                    os.replace(self.aside / name, target)
                else:
                    os.unlink(target)
            except OSError:
                not_undone.append(name)
        if self.manifest_touched:
            try:
                if MANIFEST in self.kept_aside:
                    os.replace(self.aside / MANIFEST, self.folder.manifest_path)
                else:
                    with contextlib.suppress(FileNotFoundError):
                        os.unlink(self.folder.manifest_path)
            except OSError:
                not_undone.append(MANIFEST)
        for path in reversed(self.made):
            with contextlib.suppress(OSError):
                path.rmdir()
        where = f"{self.folder.what} {self.root}"
        if not not_undone:
            shutil.rmtree(self.aside, ignore_errors=True)
            state = f"{where} is as it was before this run (nothing replaced)"
            error = ReportNotWritten(f"the report could not be written: {step} failed ({why}); {state}", True)
        else:
            shown = ", ".join(not_undone[:4]) + (", ..." if len(not_undone) > 4 else "")
            state = (f"{where} is mixed: {len(not_undone)} file(s) could not be put back ({shown}); the earlier "
                     f"ones are in {self.aside}")
            error = ReportNotWritten(f"the report could not be written: {step} failed ({why}); {state}", False)
        self.folder._interrupted_state = state
        if isinstance(exc, KeyboardInterrupt):
            raise exc
        raise error from exc
