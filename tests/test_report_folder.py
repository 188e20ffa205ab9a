"""A report folder as a unit: hand edits are refused before any work (or overwritten on purpose),
and a report is committed whole or not at all, whatever step fails. And what ``gimbal-lab run``
meets before it reaches the folder: non-finite values in ``--config``, Ctrl-C while it starts."""

from __future__ import annotations

import errno
import json
import os
import shutil
import subprocess
from pathlib import Path

import pytest

from gimbal_lab import outputs
from gimbal_lab.outputs import MANIFEST, OutputError, ReportFolder, ReportNotWritten, overwriting_edited

OLD = {"claims.md": b"# claims\nold\n", "summary.csv": b"a,b\n1,2\n", "figures/fig1.png": b"\x89PNG old figure",
       "clips/sphere.mp4": b"old clip"}
# the new report rewrites three files, adds one in a folder it makes, and leaves the clip alone
NEW = {"claims.md": b"# claims\nnew\n", "summary.csv": b"a,b\n3,4\n", "figures/fig1.png": b"\x89PNG new figure",
       "tables/verdicts.csv": b"h,verdict\nH1,supported\n"}


def _snapshot(path: Path) -> dict[str, bytes | str]:
    """Every entry under ``path`` (hidden ones and the manifest included): a file's bytes, or
    ``"<dir>"``; what "byte-identical" compares."""
    found: dict[str, bytes | str] = {}
    for p in sorted(path.rglob("*")):
        name = p.relative_to(path).as_posix()
        found[name] = "<dir>" if p.is_dir() and not p.is_symlink() else p.read_bytes()
    return found


def _write(folder: ReportFolder, files: dict[str, bytes]) -> None:
    with folder.staging() as tmp:
        for name, data in files.items():
            (tmp / name).parent.mkdir(parents=True, exist_ok=True)
            (tmp / name).write_bytes(data)


def _is_new_report(out: Path) -> bool:
    """Is ``out`` wholly the new report: NEW's files, the old clip kept, a manifest recording each?"""
    files = {k: v for k, v in _snapshot(out).items() if v != "<dir>" and k != MANIFEST}
    manifest = json.loads((out / MANIFEST).read_text())["files"]
    return (files == {**NEW, "clips/sphere.mp4": OLD["clips/sphere.mp4"]}
            and all(not entry.get("pending") for entry in manifest.values())
            and sorted(manifest) == sorted(files)
            and not any(p.name.startswith(".gimbal-lab-staging-") for p in out.iterdir()))


@pytest.fixture
def report(tmp_path) -> Path:
    out = tmp_path / "paper"
    _write(ReportFolder(out), OLD)
    return out


# ------------------------------------------------------------------------------------------------
# hand edits
# ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("edit", ["append to claims.md", "replace the figure", "same size, other bytes",
                                  "a link in its place", "a folder in its place"])
def test_an_edited_lab_file_is_refused_before_any_work_naming_it(report, edit):
    name = "figures/fig1.png" if "figure" in edit else "claims.md"
    path = report / name
    if edit == "append to claims.md":
        path.write_bytes(path.read_bytes() + b"\nMy own paragraph.\n")
    elif edit == "replace the figure":
        path.write_bytes(b"\x89PNG a figure drawn by hand, longer than the lab's")
    elif edit == "same size, other bytes":
        path.write_bytes(b"# claims\nOLD\n")
    elif edit == "a link in its place":  # to the same bytes, its own size (that of its target's name) the same
        (report.parent / "same").mkdir()
        (report.parent / "same" / "cl.md").write_bytes(OLD["claims.md"])
        path.unlink()
        path.symlink_to("../same/cl.md")
        assert len("../same/cl.md") == len(OLD["claims.md"]) == os.lstat(path).st_size
    else:
        path.unlink()
        path.mkdir()
    before = _snapshot(report)
    folder = ReportFolder(report, "the report folder")
    assert folder.edited() == [name]
    with pytest.raises(OutputError) as caught:
        folder.check()
    message = str(caught.value)
    assert "\n" not in message and message == (
        f"the report folder {report}: {name} was changed after gimbal-lab wrote it (its bytes differ from the record "
        f"in {MANIFEST}); move it away to keep it, or pass --overwrite-edited to replace it")
    ran = []
    with pytest.raises(OutputError, match=f"{name} was changed"):
        with folder.staging():
            ran.append("the report was computed")
    assert ran == [] and _snapshot(report) == before


def test_an_edit_made_while_the_report_is_computed_is_caught_before_anything_is_replaced(report):
    before_edit = _snapshot(report)
    with pytest.raises(OutputError, match="claims.md was changed"):
        with ReportFolder(report).staging() as tmp:
            (tmp / "claims.md").write_bytes(b"new")
            (report / "claims.md").write_bytes(b"edited meanwhile")
    assert _snapshot(report) == {**before_edit, "claims.md": b"edited meanwhile"}


@pytest.mark.parametrize("how", ["argument", "context"])
def test_edited_files_are_overwritten_when_asked(report, how):
    (report / "claims.md").write_bytes(b"edited by hand")
    (report / "clips/sphere.mp4").write_bytes(b"an edited clip this report does not write")
    if how == "argument":
        _write(ReportFolder(report, overwrite_edited=True), NEW)
    else:
        with overwriting_edited():
            _write(ReportFolder(report), NEW)
        with pytest.raises(OutputError, match="clips/sphere.mp4 was changed"):  # the context ended
            ReportFolder(report).check()
    assert (report / "claims.md").read_bytes() == NEW["claims.md"]
    # a file this report does not write is kept as it is (and still reported as edited)
    assert (report / "clips/sphere.mp4").read_bytes() == b"an edited clip this report does not write"
    assert ReportFolder(report).edited() == ["clips/sphere.mp4"]


def test_an_unedited_folder_and_a_deleted_file_are_taken(report):
    assert ReportFolder(report).edited() == []
    (report / "summary.csv").unlink()  # deleting a lab file is not editing it
    _write(ReportFolder(report), NEW)
    assert _is_new_report(report)


def test_a_commit_cut_short_is_taken_by_the_next_run(report, monkeypatch):
    """A process killed between the renames leaves a pending manifest: each file holds the old or
    the new bytes, both recorded, so the next run is not refused."""
    monkeypatch.setattr(outputs._Commit, "_fail", lambda self, step, exc: (_ for _ in ()).throw(SystemExit("killed")))
    real_replace, calls = os.replace, []

    def replace(src, dst):
        calls.append(dst)
        if len(calls) == 3:  # the pending manifest, then one file: then the process "dies"
            raise OSError(errno.EIO, "killed")
        real_replace(src, dst)

    monkeypatch.setattr(outputs.os, "replace", replace)
    with pytest.raises(SystemExit):
        _write(ReportFolder(report), NEW)
    monkeypatch.undo()
    for leftover in report.glob(".gimbal-lab-staging-*"):  # as the next run does once the killed one is gone
        shutil.rmtree(leftover)
    assert (report / "claims.md").read_bytes() == NEW["claims.md"] and (report / "summary.csv").read_bytes() == OLD[
        "summary.csv"]  # mixed, as a kill would leave it
    assert ReportFolder(report).edited() == []
    _write(ReportFolder(report), NEW)
    assert _is_new_report(report)


# ------------------------------------------------------------------------------------------------
# all or nothing
# ------------------------------------------------------------------------------------------------
class _FailAt:
    """Make the ``k``-th call (counting from 1) of the patched file-system functions raise ``error``
    once; every other call goes through."""

    def __init__(self, k: int, error: OSError):
        self.k, self.error, self.calls, self.armed = k, error, [], False

    def wrap(self, name, real):
        def call(*args, **kwargs):
            if self.armed:
                self.calls.append(name)
                if len(self.calls) == self.k:
                    raise self.error
            return real(*args, **kwargs)
        return call


def _commit_failing_at(out: Path, k: int, monkeypatch, error=None) -> tuple[_FailAt, BaseException | None]:
    fail = _FailAt(k, error or OSError(errno.ENOSPC, "No space left on device"))
    for module, name in ((outputs.os, "replace"), (outputs.os, "link"), (outputs.os, "mkdir"),
                         (outputs, "_write_file"), (outputs.shutil, "copy2")):
        monkeypatch.setattr(module, name, fail.wrap(name, getattr(module, name)))
    caught = None
    try:
        with ReportFolder(out, "the report folder").staging() as tmp:
            for name, data in NEW.items():
                (tmp / name).parent.mkdir(parents=True, exist_ok=True)
                (tmp / name).write_bytes(data)
            fail.armed = True  # count from the commit on
    except ReportNotWritten as exc:
        caught = exc
    finally:
        fail.armed = False
        monkeypatch.undo()
    return fail, caught


def test_a_disk_full_error_at_any_step_leaves_the_old_report_or_the_whole_new_one(report, monkeypatch, tmp_path):
    """ENOSPC injected at every file-system call of the commit in turn (keeping files aside, the
    pending manifest, each folder made, each rename, the last manifest): after each, the folder is
    byte for byte as before with a message saying so, or wholly the new report."""
    before = _snapshot(report)
    outcomes, k = [], 1
    while True:
        out = tmp_path / f"k{k}"
        shutil.copytree(report, out, symlinks=True)
        fail, caught = _commit_failing_at(out, k, monkeypatch)
        if len(fail.calls) < k:  # no call left to fail: the commit ran through
            assert caught is None and _is_new_report(out)
            break
        step = fail.calls[k - 1]
        if caught is None:  # a failed link falls back to a copy: the commit goes on
            assert step == "link" and _is_new_report(out), (k, step)
            outcomes.append("new")
        else:
            assert caught.unchanged and _snapshot(out) == before, (k, step, str(caught))
            assert str(caught).endswith(f"the report folder {out} is as it was before this run (nothing replaced)")
            assert "\n" not in str(caught) and "No space left on device" in str(caught)
            outcomes.append("old")
        k += 1
    # every kind of step was hit, and most failures fell on a step after which something had changed
    assert set(fail.calls) == {"link", "mkdir", "replace", "_write_file"}, fail.calls
    assert outcomes.count("old") >= 8 and len(outcomes) == len(fail.calls)


def test_a_folder_in_a_files_place_stops_the_commit_before_anything_changes(report):
    (report / "summary.csv").unlink()
    (report / "summary.csv").mkdir()  # e.g. an empty folder named like the lab's table
    before = _snapshot(report)
    with pytest.raises(ReportNotWritten) as caught:
        _write(ReportFolder(report, "the report folder", overwrite_edited=True), NEW)
    assert caught.value.unchanged and _snapshot(report) == before
    assert str(caught.value) == (f"the report could not be written: keeping the files it replaces aside failed (a "
                                 f"folder is where the report's file goes: {report / 'summary.csv'}); the report "
                                 f"folder {report} is as it was before this run (nothing replaced)")


def _immutable(path: Path) -> bool:
    return subprocess.run(["chattr", "+i", str(path)], capture_output=True).returncode == 0


def test_an_immutable_file_rolls_the_whole_report_back(report):
    target = report / "summary.csv"  # renamed after claims.md and the figure: those are rolled back
    if shutil.which("chattr") is None or not _immutable(target):
        pytest.skip("chattr +i is not allowed here (the folder-in-a-file's-place test covers a rename that fails)")
    try:
        before = _snapshot(report)
        with pytest.raises(ReportNotWritten) as caught:
            _write(ReportFolder(report, "the report folder"), NEW)
        assert caught.value.unchanged and _snapshot(report) == before
        assert str(caught.value) == (f"the report could not be written: renaming summary.csv into place failed "
                                     f"(Operation not permitted); the report folder {report} is as it was before "
                                     "this run (nothing replaced)")
    finally:
        subprocess.run(["chattr", "-i", str(target)], check=True)
    _write(ReportFolder(report), NEW)  # once the file may change again, the report goes in whole
    assert _is_new_report(report)


def test_when_the_old_files_cannot_be_put_back_the_message_says_where_they_are(report, monkeypatch):
    real_replace, calls = os.replace, []

    def replace(src, dst):
        calls.append(Path(dst).name)
        # the third rename into place fails (disk full), and so does every rename back after it
        if len(calls) == 4 or (len(calls) > 4 and ".gimbal-lab-staging-" in str(src)):
            raise OSError(errno.ENOSPC, "No space left on device", str(dst))
        real_replace(src, dst)

    monkeypatch.setattr(outputs.os, "replace", replace)
    with pytest.raises(ReportNotWritten) as caught:
        _write(ReportFolder(report, "the report folder"), NEW)
    monkeypatch.undo()
    message = str(caught.value)
    assert not caught.value.unchanged and "\n" not in message
    aside = message.rsplit("the earlier ones are in ", 1)[1]
    assert f"the report folder {report} is mixed: 3 file(s) could not be put back (" in message
    kept = _snapshot(Path(aside))
    assert kept["claims.md"] == OLD["claims.md"] and kept["figures/fig1.png"] == OLD["figures/fig1.png"]


# ------------------------------------------------------------------------------------------------
# the command line: gimbal-lab run --overwrite-edited
# ------------------------------------------------------------------------------------------------
@pytest.fixture
def fake_paper(monkeypatch):
    """``gimbal-lab run paper`` with the study's run replaced by one that writes NEW through a
    ReportFolder made as the studies make theirs (no ``overwrite_edited`` argument)."""
    from gimbal_lab import runner
    from gimbal_lab.studies import paper

    def run_study(params, out, **kwargs):
        folder = ReportFolder(Path(out) / "paper", "the report folder")
        folder.check()
        _write(folder, NEW)
        return {"folder": folder.path, "written": folder.written, "kept": folder.kept, "verdicts": None}

    monkeypatch.setattr(paper, "run_study", run_study)
    monkeypatch.setattr(runner, "run", lambda *a, **k: pytest.fail("a run was computed"))


def _cli(argv, capsys) -> tuple[int, str]:
    from gimbal_lab import cli

    try:
        status = cli.main(argv)
    except SystemExit as exc:
        status = exc.code
    return status, capsys.readouterr().err


def test_the_command_line_refuses_an_edited_report_and_overwrites_it_when_told(tmp_path, fake_paper, capsys):
    out = tmp_path / "results"
    argv = ["run", "paper", "--out", str(out), "--store", str(tmp_path / "store"), "--quiet"]
    _write(ReportFolder(out / "paper"), OLD)
    (out / "paper" / "claims.md").write_bytes(b"my own claims")
    before = _snapshot(out / "paper")
    status, err = _cli(argv, capsys)
    assert status == 2 and err == (f"gimbal-lab run: error: the report folder {out / 'paper'}: claims.md was changed "
                                   f"after gimbal-lab wrote it (its bytes differ from the record in {MANIFEST}); move "
                                   "it away to keep it, or pass --overwrite-edited to replace it\n")
    assert _snapshot(out / "paper") == before
    status, err = _cli(argv + ["--overwrite-edited"], capsys)
    assert status == 0, err
    assert _is_new_report(out / "paper")


def test_the_command_line_says_the_folder_is_unchanged_when_the_commit_fails(tmp_path, fake_paper, capsys):
    out = tmp_path / "results"
    _write(ReportFolder(out / "paper"), OLD)
    (out / "paper" / "summary.csv").unlink()
    (out / "paper" / "summary.csv").mkdir()
    before = _snapshot(out / "paper")
    status, err = _cli(["run", "paper", "--out", str(out), "--store", str(tmp_path / "store"), "--quiet",
                        "--overwrite-edited"], capsys)
    assert status == 1 and err.count("\n") == 1 and "Traceback" not in err
    assert err.startswith("gimbal-lab run: error: the report could not be written: keeping the files it replaces aside "
                          "failed") and err.endswith(f"the report folder {out / 'paper'} is as it was before this run "
                                                     "(nothing replaced)\n"), err
    assert _snapshot(out / "paper") == before



# ------------------------------------------------------------------------------------------------
# before the report: bad config values, Ctrl-C at start
# ------------------------------------------------------------------------------------------------
def _numeric_fields() -> list[tuple[str, str, str]]:
    """(study, its TOML table, field) for every number a study's --config may set."""
    from dataclasses import fields

    from gimbal_lab.studies import STUDIES, load

    found = []
    for name in STUDIES:
        study = load(name).Study
        for f in fields(study):
            value = getattr(study(), f.name)
            if isinstance(value, (int, float)) and not isinstance(value, bool):
                found.append((name, study._TABLE, f.name))
    return found


def test_non_finite_config_values_are_a_validation_line(tmp_path, capsys, monkeypatch):
    """The campaign's bad-config family: every number of every study's --config set to nan, inf
    and -inf (TOML's own literals): each is exit 2 and one line naming the field, before any run."""
    from gimbal_lab import runner

    monkeypatch.setattr(runner, "run", lambda *a, **k: pytest.fail("a run was computed"))
    cases = [(study, table, field, literal) for study, table, field in _numeric_fields()
             for literal in ("nan", "inf", "-inf")]
    assert len(cases) >= 140  # 49 numbers in 6 studies (a field added later adds cases)
    for study, table, field, literal in cases:
        config = tmp_path / f"{study}-{field}.toml"
        config.write_text(f"[{table}]\n{field} = {literal}\n")
        status, err = _cli(["run", study, "--config", str(config), "--out", str(tmp_path / "out")], capsys)
        value = {"nan": "nan", "inf": "inf", "-inf": "-inf"}[literal]
        assert status == 2 and err == f"gimbal-lab run: error: {field} must be a finite number, got {value}\n", (
            study, field, literal, err)


def test_non_finite_values_inside_a_field_are_named_with_their_place():
    from gimbal_lab.studies._params import _check_finite

    _check_finite("ok", [1.0, {"a": (2, 3.5)}, "nan"])  # the string "nan" is not a number
    with pytest.raises(ValueError, match=r"^grid\[1\]\.gain must be a finite number, got inf$"):
        _check_finite("grid", [0.5, {"gain": float("inf")}])


#: Seeded instants of the first 2 s of ``gimbal-lab run``'s start (the test's own random stream).
CTRL_C_INSTANTS_S = sorted(float(t) for t in __import__("numpy").random.default_rng(2042).uniform(0.0, 2.0, 20))


def test_ctrl_c_at_any_instant_of_start_up_is_one_line_and_exit_130(tmp_path):
    """SIGINT at 20 seeded instants of the first 2 s of ``gimbal-lab run paper`` (imports, parsing,
    the first runs): never a traceback from the package, exit 130 and one line. The interpreter's
    own start-up, before the console script imports the package, is beyond its reach (Python
    prints a KeyboardInterrupt traceback there, with no frame of gimbal_lab, or the process dies
    of the signal before Python handles it): such an instant is counted, and at least 8 of the 20
    must reach the package (its start-up lasts 0.03 to 0.4 s, longer on a loaded machine), so the
    test always checks the package's own handling."""
    import signal
    import sys
    from concurrent.futures import ThreadPoolExecutor

    exe = Path(sys.executable).parent / "gimbal-lab"
    config = tmp_path / "tiny.toml"
    config.write_text("[paper]\nreplicates = 2\nperiod_s = 0.3\n")
    env = {**os.environ, "PYOPENGL_PLATFORM": "egl", "LP_NUM_THREADS": "1"}

    def interrupt(i_t):
        i, t = i_t
        proc = subprocess.Popen([str(exe), "run", "paper", "--config", str(config), "--out", str(tmp_path / f"o{i}"),
                                 "--store", str(tmp_path / f"s{i}"), "--quiet", "--jobs", "1"],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
        t0 = __import__("time").monotonic()
        __import__("time").sleep(max(0.0, t - (__import__("time").monotonic() - t0)))
        proc.send_signal(signal.SIGINT)
        try:
            _, err = proc.communicate(timeout=60)
        finally:
            proc.kill()
        return t, proc.returncode, err

    with ThreadPoolExecutor(4) as pool:
        outcomes = list(pool.map(interrupt, enumerate(CTRL_C_INSTANTS_S)))
    interpreter = 0
    for t, status, err in outcomes:
        if (status == -signal.SIGINT and not err) or ("KeyboardInterrupt" in err and "/gimbal_lab/" not in err):
            interpreter += 1  # Python's own start-up (before its handler; site; the script's first import)
            continue
        lines = err.strip().splitlines()
        assert status == 130 and "Traceback" not in err and "Exception ignored" not in err, (t, status, err)
        assert len(lines) == 1 and lines[0] in ("gimbal-lab: interrupted", "gimbal-lab run: interrupted"), (t, err)
    # the interpreter's own start-up takes 0.05-0.4 s at light load and more on a loaded machine:
    # its instants are beyond the package's reach, so the check is that enough instants reach it
    assert len(outcomes) - interpreter >= 8, outcomes


def test_the_command_itself_runs_with_ctrl_c_as_keyboard_interrupt(monkeypatch):
    """Start-up's one-line handler gives way to KeyboardInterrupt while the command runs (a sweep
    says what it keeps), and comes back for the interpreter's exit."""
    import signal

    from gimbal_lab import cli
    from gimbal_lab.studies import cli as studies_cli

    seen = []
    monkeypatch.setattr(studies_cli, "_run", lambda args, parser: seen.append(signal.getsignal(signal.SIGINT)) or 0)
    previous = signal.signal(signal.SIGINT, cli._interrupted_at_start)  # as the console script sets it
    try:
        assert cli.main(["run", "paper"]) == 0
        assert isinstance(seen[0], cli._CtrlC)
        with pytest.raises(KeyboardInterrupt):
            seen[0](signal.SIGINT, None)
        assert seen[0].received
        assert signal.getsignal(signal.SIGINT) is cli._interrupted_at_start
    finally:
        signal.signal(signal.SIGINT, previous)
    assert not cli._launched()  # imported by a test: the process's handler is left alone


def test_a_ctrl_c_whose_error_names_no_interrupt_is_still_an_interruption(monkeypatch, capsys):
    """numpy's ImportError after a Ctrl-C amid its C extensions can carry no KeyboardInterrupt at
    all (the C code cleared it): the handler's note that SIGINT came decides."""
    import signal

    from gimbal_lab import cli
    from gimbal_lab.studies import cli as studies_cli

    def run(args, parser):
        try:
            signal.getsignal(signal.SIGINT)(signal.SIGINT, None)  # the Ctrl-C, as the handler meets it
        except KeyboardInterrupt:
            pass  # swallowed by C code
        raise ImportError('PyCapsule_Import could not import module "datetime"')

    monkeypatch.setattr(studies_cli, "_run", run)
    previous = signal.signal(signal.SIGINT, cli._interrupted_at_start)
    try:
        status, err = _cli(["run", "paper"], capsys)
    finally:
        signal.signal(signal.SIGINT, previous)
    assert status == 130 and err == "\ngimbal-lab run: interrupted\n"


@pytest.mark.parametrize("chained", ["from", "during"])
def test_an_error_a_library_raises_for_a_ctrl_c_is_an_interruption(monkeypatch, capsys, chained):
    """numpy turns a KeyboardInterrupt amid the import of its C extensions into an ImportError
    (found at 1 of 60 instants): the command line reports the interruption, exit 130."""
    from gimbal_lab.studies import cli as studies_cli

    def run(args, parser):
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt as exc:
            if chained == "from":
                raise ImportError("Importing the numpy C-extensions failed") from exc
            raise ImportError("Importing the numpy C-extensions failed")  # noqa: B904 - as numpy does

    monkeypatch.setattr(studies_cli, "_run", run)
    status, err = _cli(["run", "paper"], capsys)
    assert status == 130 and err == "\ngimbal-lab run: interrupted\n"


def test_an_import_error_of_its_own_is_still_an_error(monkeypatch, capsys):
    from gimbal_lab.studies import cli as studies_cli

    def run(args, parser):
        raise ImportError("no module named nosuch")

    monkeypatch.setattr(studies_cli, "_run", run)
    status, err = _cli(["run", "paper"], capsys)
    assert status == 1 and "ImportError: no module named nosuch (an unexpected error" in err


def test_a_ctrl_c_at_start_ends_the_process_even_where_python_ignores_exceptions(tmp_path):
    """Found at 1 of 60 instants: the start-up handler ran inside a weak reference's callback of
    the import system, where a raised exception is printed as 'Exception ignored' and dropped, and
    the command ran on. The handler ends the process itself: exit 130, one line, nothing after."""
    import sys

    script = (
        "import weakref, sys\n"
        "from gimbal_lab import cli\n"
        "class Thing: pass\n"
        "thing = Thing()\n"
        "ref = weakref.ref(thing, lambda r: cli._interrupted_at_start(2, None))\n"
        "print('printed before', flush=False)\n"
        "del thing  # the callback runs here; an exception from it would be ignored\n"
        "print('the command ran on')\n")
    env = {k: v for k, v in os.environ.items() if k != "PYTHONUNBUFFERED"}  # stdout a buffered pipe, as usual
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60, env=env)
    assert done.returncode == 130 and done.stdout == "printed before\n", done
    assert done.stderr == "\ngimbal-lab: interrupted\n"


KILLED_COMMIT = """
import os, signal, sys
from pathlib import Path
from gimbal_lab import outputs
out, k, files = Path(sys.argv[1]), int(sys.argv[2]), eval(sys.argv[3])
real, calls = os.replace, []

def replace(src, dst):
    calls.append(dst)
    if len(calls) == k:
        os.kill(os.getpid(), signal.SIGKILL)  # the process dies here, as under the OOM killer or kill -9
    real(src, dst)

outputs.os.replace = replace
with outputs.ReportFolder(out).staging() as tmp:
    for name, data in files.items():
        (tmp / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp / name).write_bytes(data)
print("committed", len(calls), flush=True)
"""


def test_a_commit_killed_at_any_rename_is_undone_by_the_next_run(tmp_path):
    """SIGKILL at each rename of a commit (the pending manifest, each file, the last manifest):
    the next run's check puts the earlier report back byte for byte (or, killed after its last
    manifest, keeps the whole new one), and then writes its own report whole."""
    import sys

    k, outcomes = 1, []
    while True:
        out = tmp_path / f"k{k}"
        _write(ReportFolder(out), OLD)
        before = _snapshot(out)
        done = subprocess.run([sys.executable, "-c", KILLED_COMMIT, str(out), str(k), repr(NEW)],
                              capture_output=True, text=True, timeout=120)
        if done.returncode == 0:
            assert done.stdout.startswith("committed") and _is_new_report(out)
            break
        assert done.returncode == -9, done.stderr
        ReportFolder(out).check()
        after = _snapshot(out)
        if after == before:
            outcomes.append("old")
        else:
            assert _is_new_report(out), (k, sorted(after))
            outcomes.append("new")
        _write(ReportFolder(out), NEW)
        assert _is_new_report(out)
        k += 1
    # the pending manifest, 4 files, the last manifest: killed at the first five, the old report;
    # at the last, the new one is whole once its manifest is in place (killed before it: old)
    assert outcomes == ["old"] * 6, outcomes
