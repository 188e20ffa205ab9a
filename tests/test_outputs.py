"""Output files whole or absent, and only the lab's own: report folders with a manifest, files
written through temporary names, output paths checked before any work."""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from gimbal_lab import outputs
from gimbal_lab.outputs import (MANIFEST, OutputError, ReportFolder, ReportInterrupted, atomic_path, check_new_file,
                                check_writable_folder)


def _tree(path: Path) -> dict[str, str]:
    """Every file under ``path`` but the manifest, with its text."""
    return {p.relative_to(path).as_posix(): p.read_text() for p in sorted(path.rglob("*"))
            if p.is_file() and p.name != MANIFEST}


def _report(folder: ReportFolder, files: dict[str, str]) -> None:
    with folder.staging() as tmp:
        for name, text in files.items():
            (tmp / name).parent.mkdir(parents=True, exist_ok=True)
            (tmp / name).write_text(text)


# ------------------------------------------------------------------------------------------------
# report folders
# ------------------------------------------------------------------------------------------------
def test_a_report_replaces_its_own_files_and_keeps_the_ones_it_did_not_write_again(tmp_path):
    out = tmp_path / "paper"
    folder = ReportFolder(out)
    _report(folder, {"claims.md": "1", "figures/a.png": "1", "clips/sphere.mp4": "1"})
    assert _tree(out) == {"claims.md": "1", "figures/a.png": "1", "clips/sphere.mp4": "1"}
    assert sorted(p.name for p in folder.written) == ["a.png", "claims.md", "sphere.mp4"] and folder.kept == []
    manifest = json.loads((out / MANIFEST).read_text())
    assert sorted(manifest["files"]) == ["claims.md", "clips/sphere.mp4", "figures/a.png"]
    assert manifest["files"]["claims.md"]["bytes"] == 1

    _report(folder, {"claims.md": "2", "figures/a.png": "2"})  # a second run, without clips
    assert _tree(out) == {"claims.md": "2", "figures/a.png": "2", "clips/sphere.mp4": "1"}
    assert folder.kept == [out / "clips" / "sphere.mp4"]
    assert sorted(json.loads((out / MANIFEST).read_text())["files"]) == ["claims.md", "clips/sphere.mp4",
                                                                         "figures/a.png"]
    assert sorted(p.name for p in out.iterdir()) == [MANIFEST, "claims.md", "clips", "figures"]  # no staging left


@pytest.mark.parametrize("foreign", ["my_notes.txt", "figures/extra.png", "thesis.tex"])
def test_a_folder_holding_a_file_the_lab_did_not_write_is_refused_and_left_alone(tmp_path, foreign):
    out = tmp_path / "paper"
    _report(ReportFolder(out), {"claims.md": "1", "figures/a.png": "1"})
    (out / foreign).parent.mkdir(parents=True, exist_ok=True)
    (out / foreign).write_text("mine")
    before = _tree(out)
    folder = ReportFolder(out, "the report folder")
    with pytest.raises(OutputError) as caught:
        folder.check()
    message = str(caught.value)
    assert "\n" not in message and message.startswith(f"the report folder {out} holds {foreign}, which gimbal-lab "
                                                       "did not write"), message
    with pytest.raises(OutputError):
        _report(folder, {"claims.md": "2"})
    assert _tree(out) == before  # nothing replaced, nothing deleted


def test_a_folder_the_lab_never_wrote_is_refused_naming_the_first_file(tmp_path):
    out = tmp_path / "paper"
    out.mkdir()
    for name in ("thesis.tex", "figures/f.pdf", "a.bib"):
        (out / name).parent.mkdir(exist_ok=True)
        (out / name).write_text("x")
    with pytest.raises(OutputError, match=r"holds a\.bib \(and 2 more\), which gimbal-lab did not write"):
        ReportFolder(out).check()
    empty = tmp_path / "empty"
    empty.mkdir()
    _report(ReportFolder(empty), {"claims.md": "1"})  # an empty folder is taken
    assert _tree(empty) == {"claims.md": "1"}


def test_a_file_that_appears_during_the_run_is_caught_before_anything_is_replaced(tmp_path):
    out = tmp_path / "paper"
    _report(ReportFolder(out), {"claims.md": "1"})
    with pytest.raises(OutputError, match="holds late.txt"):
        with ReportFolder(out).staging() as tmp:
            (tmp / "claims.md").write_text("2")
            (out / "late.txt").write_text("written while the report was computed")
    assert _tree(out) == {"claims.md": "1", "late.txt": "written while the report was computed"}


@pytest.mark.parametrize("error", [RuntimeError, KeyboardInterrupt])
def test_an_error_while_writing_leaves_the_folder_as_it_was(tmp_path, error):
    out = tmp_path / "paper"
    _report(ReportFolder(out), {"claims.md": "old"})
    expected = ReportInterrupted if error is KeyboardInterrupt else error
    with pytest.raises(expected) as caught:
        with ReportFolder(out).staging() as tmp:
            (tmp / "claims.md").write_text("half written")
            raise error("boom")
    if error is KeyboardInterrupt:
        assert str(caught.value) == f"interrupted while writing the report: {out} is unchanged"
    assert _tree(out) == {"claims.md": "old"}
    assert sorted(p.name for p in out.iterdir()) == [MANIFEST, "claims.md"]

    new = tmp_path / "never" / "paper"  # a folder this call made is removed again; one that was there, kept
    with pytest.raises(expected):
        with ReportFolder(new).staging():
            raise error("boom")
    assert not new.exists()
    there = tmp_path / "there"
    there.mkdir()
    with pytest.raises(expected):
        with ReportFolder(there).staging():
            raise error("boom")
    assert there.is_dir()


def test_ctrl_c_while_files_are_renamed_lands_after_the_whole_report(tmp_path, monkeypatch):
    """SIGINT during the renames is held back: every file is the new one, and the message says so."""
    out = tmp_path / "paper"
    _report(ReportFolder(out), {f"{i}.txt": "old" for i in range(5)})
    real_replace = os.replace
    calls = []

    def replace(src, dst):
        calls.append(dst)
        if len(calls) == 3:
            os.kill(os.getpid(), signal.SIGINT)
        real_replace(src, dst)

    monkeypatch.setattr(outputs.os, "replace", replace)
    with pytest.raises(ReportInterrupted, match=f"interrupted after the report was written whole to {out}"):
        _report(ReportFolder(out), {f"{i}.txt": "new" for i in range(5)})
    monkeypatch.undo()
    assert _tree(out) == {f"{i}.txt": "new" for i in range(5)}
    assert len(calls) > 5  # the five files and the manifest


def test_leftovers_of_dead_writers_are_removed_and_live_ones_kept(tmp_path):
    out = tmp_path / "paper"
    _report(ReportFolder(out), {"claims.md": "1"})
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    host = outputs._HOST

    def tag(pid, check=None):  # what outputs.unique_tag makes for ``pid`` (or a wrong check tag)
        core = f"{host}-{pid}-0a0b0c0d"
        return f"{core}-{check or outputs._check_tag(core)}"

    dead_staging = out / f".gimbal-lab-staging-{tag(dead.pid)}"
    live_staging = out / f".gimbal-lab-staging-{tag(os.getppid())}"
    dead_tmp = out / f".claims.partial-{tag(dead.pid)}.md"
    # named like the lab's temporary files, with a dead pid, but not made by it (no or a wrong tag)
    lookalikes = [out / f".gimbal-lab-staging-{host}-{dead.pid}-0a0b0c0d", out / f".gimbal-lab-staging-{tag(dead.pid, 'ffffff')}",
                  out / f".notes.partial-{host}-{dead.pid}-0a0b0c0d.md", out / f".notes.partial-{tag(dead.pid, '000000')}.md"]
    for d in (dead_staging, live_staging, *lookalikes[:2]):
        d.mkdir()
        (d / "x").write_text("x")
    for f in (dead_tmp, *lookalikes[2:]):
        f.write_text("torn")
    _report(ReportFolder(out), {"claims.md": "2"})  # neither is taken for a file of someone else's
    assert not dead_staging.exists() and not dead_tmp.exists()
    assert live_staging.exists()
    assert all(p.exists() for p in lookalikes)  # a user's files that look like leftovers survive
    assert _tree(out)["claims.md"] == "2"


def _finish_reports_together(out: str, tag: str, rounds: int, barrier, errors) -> None:
    """One writer of ``out``: each round, write a whole report and leave the block at the same
    instant as the other writers (a barrier); the first writer then checks the folder is whole."""
    for r in range(rounds):
        try:
            barrier.wait()
            with ReportFolder(out).staging() as tmp:
                for i in range(4):
                    (tmp / f"{i}.txt").write_text(f"{tag} {r}")
                barrier.wait()
        except Exception as exc:  # noqa: BLE001 - reported to the test
            errors.append(f"{tag} round {r}: {exc!r}")
        barrier.wait()
        if tag == "0":
            texts = {p.name: p.read_text() for p in Path(out).iterdir() if p.name != MANIFEST}
            writers = set(texts.values())
            if sorted(texts) != ["0.txt", "1.txt", "2.txt", "3.txt"] or len(writers) != 1 or \
                    not next(iter(writers)).endswith(f" {r}"):
                errors.append(f"round {r}: a mixed or missing report {texts}")
        barrier.wait()


def _writer_process(out, tag, rounds, barrier, queue):
    errors: list = []
    _finish_reports_together(out, tag, rounds, barrier, errors)
    queue.put(errors)


@pytest.mark.parametrize("writers", ["processes", "threads"])
def test_reports_finishing_at_the_same_instant_never_mix_or_fail(tmp_path, writers):
    """Forced races: 3 writers commit to one folder together, 40 times over; every commit must
    succeed and the folder must always hold one writer's whole report of that round."""
    import multiprocessing
    import threading

    out, n, rounds = str(tmp_path / "report"), 3, 40
    if writers == "threads":
        barrier, errors = threading.Barrier(n), []
        threads = [threading.Thread(target=_finish_reports_together, args=(out, str(i), rounds, barrier, errors))
                   for i in range(n)]
        for t in threads:
            t.start()
        for t in threads:
            t.join(timeout=120)
    else:
        ctx = multiprocessing.get_context("spawn")
        barrier, queue = ctx.Barrier(n, timeout=60), ctx.Queue()
        procs = [ctx.Process(target=_writer_process, args=(out, str(i), rounds, barrier, queue)) for i in range(n)]
        for p in procs:
            p.start()
        errors = [e for _ in procs for e in queue.get(timeout=180)]
        for p in procs:
            p.join(timeout=30)
    assert errors == []
    assert sorted(p.name for p in Path(out).iterdir()) == sorted(["0.txt", "1.txt", "2.txt", "3.txt", MANIFEST])


@pytest.mark.parametrize("path", ["", "   "])
def test_report_folders_reject_empty_paths(path):
    with pytest.raises(OutputError, match="must be a non-empty path"):
        ReportFolder(path)


def test_a_damaged_manifest_is_named(tmp_path):
    out = tmp_path / "paper"
    out.mkdir()
    (out / MANIFEST).write_text("{not json")
    with pytest.raises(OutputError, match=f"its manifest {MANIFEST} cannot be read"):
        ReportFolder(out).check()


# ------------------------------------------------------------------------------------------------
# single files and output paths
# ------------------------------------------------------------------------------------------------
def test_atomic_path_replaces_on_success_and_keeps_the_old_file_otherwise(tmp_path):
    target = tmp_path / "sub" / "cam.yaml"
    with atomic_path(target) as tmp:
        assert tmp.parent == target.parent and tmp.suffix == ".yaml" and tmp.name.startswith(".cam.partial-")
        tmp.write_text("good")
    assert target.read_text() == "good"
    for error in (RuntimeError, KeyboardInterrupt):
        with pytest.raises(error):
            with atomic_path(target) as tmp:
                tmp.write_text("half")
                raise error("boom")
    with pytest.raises(ValueError, match="nothing was written to"):
        with atomic_path(target):
            pass
    assert target.read_text() == "good"
    assert sorted(p.name for p in target.parent.iterdir()) == ["cam.yaml"]


@contextlib.contextmanager
def unwritable(folder: Path):
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


def test_output_paths_are_checked_in_one_line(tmp_path):
    a_file = tmp_path / "afile"
    a_file.write_text("x")
    cases = [
        (lambda: check_writable_folder(a_file, "--out"), f"--out {a_file} is a file, not a folder"),
        (lambda: check_writable_folder("/dev/null", "--out"), "--out /dev/null is a device or special file, not a folder"),
        (lambda: check_writable_folder(a_file / "sub", "--out"), f"--out {a_file / 'sub'} cannot be made: {a_file} is a file"),
        (lambda: check_new_file(tmp_path, "--out"), f"--out {tmp_path} is a folder; give a file name"),
        (lambda: check_new_file(a_file / "clip.mp4", "--out"), f"cannot be written: {a_file} is a file, not a folder"),
        (lambda: check_new_file(tmp_path / "clip.avi", "--out", suffixes=(".mp4", ".gif")), "must end in .mp4 or .gif"),
        (lambda: check_new_file("/dev/null", "--out"), "/dev/null is not a regular file"),
    ]
    for call, message in cases:
        with pytest.raises(OutputError) as caught:
            call()
        assert message in str(caught.value) and "\n" not in str(caught.value), str(caught.value)
    assert check_writable_folder(tmp_path / "new" / "deeper") == tmp_path / "new" / "deeper"  # creatable: fine
    assert not (tmp_path / "new").exists()  # and nothing was made


def test_an_unwritable_folder_is_named(tmp_path):
    shared = Path(os.environ.get("TMPDIR", "/tmp")) / f"gimbal-outputs-{os.getpid()}"
    shared.mkdir()
    try:
        shared.chmod(0o755)
        locked = shared / "locked"
        locked.mkdir()
        with unwritable(locked):
            with pytest.raises(OutputError, match=f"--out {locked / 'paper'} cannot be made: {locked} is not writable "
                                                  r"\(permission denied or a read-only file system\)"):
                check_writable_folder(locked / "paper", "--out")
            with pytest.raises(OutputError, match=f"--out {locked} is not writable"):
                check_writable_folder(locked, "--out")
            with pytest.raises(OutputError, match=f"--out {locked / 'c.mp4'} cannot be written: {locked} is not "
                                                  "writable"):
                check_new_file(locked / "c.mp4", "--out")
    finally:
        import shutil

        shutil.rmtree(shared, ignore_errors=True)
