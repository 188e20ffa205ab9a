"""The command line as a user meets it: every error one line naming the culprit, with no
traceback and a non-zero exit (2 for a bad argument or output path, found before any work; 1 for
a failure while working; 130 for Ctrl-C, saying what a rerun reuses); ``--debug`` shows the
traceback; ``--help`` imports nothing heavy; a run replaces only the files it wrote."""

from __future__ import annotations

import json
import os
import struct
import subprocess
import sys
import zlib
from pathlib import Path

import pytest

from gimbal_lab import cli, runner
from gimbal_lab.outputs import MANIFEST
from gimbal_lab.studies import paper

HEAVY = ("numpy", "cv2", "pyrender", "scipy", "pandas", "pymavlink", "matplotlib", "pyarrow", "av", "OpenGL")
TINY = "[paper]\nreplicates = 2\nperiod_s = 0.3\n"  # 32 runs of 2 revolutions of 9 frames


def call(argv, capsys) -> tuple[int, str, str]:
    """Run ``gimbal-lab ARGV`` in this process; (exit status, stdout, stderr)."""
    try:
        status = cli.main(argv)
    except SystemExit as exc:
        status = exc.code
    out, err = capsys.readouterr()
    return status, out, err


def assert_one_line(err: str, *needles: str) -> None:
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    for needle in needles:
        assert needle in lines[0], err


@pytest.fixture
def no_runs(monkeypatch):
    """Fail the test if any closed-loop run is computed (errors must come before any work)."""
    def refuse(*args, **kwargs):
        raise AssertionError("a run was computed")

    monkeypatch.setattr(runner, "run", refuse)


@pytest.fixture(autouse=True)
def own_store(tmp_path, monkeypatch):
    """Each test's runs in a store of its own (TMP/store) unless it names another."""
    monkeypatch.setenv(runner.STORE_ENV, str(tmp_path / "store"))


@pytest.fixture
def tiny(tmp_path):
    path = tmp_path / "tiny.toml"
    path.write_text(TINY)
    return path


# ------------------------------------------------------------------------------------------------
# start-up
# ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("argv", [["--help"], ["run", "--help"], ["show", "--help"], ["calibrate", "--help"],
                                  ["track", "--help"], ["gimbal-device", "--help"], ["--version"]])
def test_help_imports_nothing_heavy(argv):
    """Building the parser and answering --help loads none of numpy, OpenCV, the renderer, SciPy,
    pandas, pymavlink, matplotlib, pyarrow or PyAV (each costs seconds under load)."""
    code = ("import json, sys\nfrom gimbal_lab import cli\ntry:\n    cli.main(sys.argv[1:])\nexcept SystemExit:\n"
            "    pass\nprint(json.dumps([m for m in sys.modules if m.split('.')[0] in %r]))" % (HEAVY,))
    done = subprocess.run([sys.executable, "-c", code, *argv], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    assert json.loads(done.stdout.strip().splitlines()[-1]) == []


# ------------------------------------------------------------------------------------------------
# bad arguments: exit 2, one line, before any work
# ------------------------------------------------------------------------------------------------
TRACK = ["track", "in.mp4", "--target", "aruco", "--calibration", "cam.yaml", "--out", "o"]


@pytest.mark.parametrize("argv, message", [
    (["run", "paper", "--jobs", "0"], "gimbal-lab run: error: argument --jobs: must be an integer >= 1, got '0'"),
    (["run", "nosuch"], "unknown study 'nosuch'; known studies: exposure, lens-sweep, light, link, moving-drone, occlusion, paper, payoff"),
    (["run", "paper", "--points", "12"], "gimbal-lab run: error: --points sets a map's points (payoff, light); paper has none"),
    (["run", "payoff", "--points", "9"], "gimbal-lab run: error: argument --points: must be an integer >= 12, got '9'"),
    (["run", "payoff", "--points", "abc"], "argument --points: must be an integer >= 12, got 'abc'"),
    (["run"], "name a study (gimbal-lab run --list shows them)"),
    (["calibrate", "boards", "--square", "nan"], "argument --square: must be a finite length in metres > 0, got 'nan'"),
    (["calibrate", "boards", "--square", "0"], "argument --square: must be a finite length in metres > 0, got '0'"),
    (["calibrate", "boards", "--square", "inf"], "argument --square: must be a finite length in metres > 0, got 'inf'"),
    (["calibrate", "boards", "--square", "-1"], "argument --square: must be a finite length in metres > 0, got '-1'"),
    (["calibrate", "boards", "--max-frames", "-1"], "argument --max-frames: must be an integer >= 1, got '-1'"),
    (["calibrate", "boards", "--step", "0"], "argument --step: must be an integer >= 1, got '0'"),
    (["calibrate", "boards", "--board", "charuco"], "--board charuco needs --marker METRES"),
    (["calibrate", "boards", "--board", "charuco", "--marker", "0.03"], "--marker (0.03 m) must be smaller than --square"),
    (["calibrate", "boards", "--out", "cam.txt"], "--out cam.txt must end in .yaml or .yml or .xml or .json"),
    (TRACK + ["--max-frames", "-1"], "argument --max-frames: must be an integer >= 1, got '-1'"),
    (TRACK + ["--marker-length", "nan"], "argument --marker-length: must be a finite length in metres > 0"),
    (TRACK + ["--radius", "0"], "argument --radius: must be a finite length in metres > 0, got '0'"),
    (["show", "--every", "0"], "argument --every: must be an integer >= 1, got '0'"),
    (["show", "--seed", "-1"], "argument --seed: must be an integer >= 0, got '-1'"),
    (["show", "--out", "clip.avi"], "--out clip.avi must end in .mp4 or .gif"),
    (["show", "--target", "cube"], "argument --target: invalid choice: 'cube'"),
])
def test_bad_arguments_exit_2_in_one_line(argv, message, capsys, tmp_path, monkeypatch, no_runs):
    monkeypatch.chdir(tmp_path)
    status, _, err = call(argv, capsys)
    assert status == 2
    assert_one_line(err, message)
    assert sorted(os.listdir(tmp_path)) == []  # nothing written


def test_bad_output_paths_are_refused_before_any_work(capsys, tmp_path, monkeypatch, no_runs, tiny):
    monkeypatch.chdir(tmp_path)
    Path("afile").write_text("x")
    Path("adir").mkdir()
    (Path("adir") / "track.csv").mkdir()
    cases = [
        (["run", "paper", "--out", "afile"], "gimbal-lab run: error: --out afile is a file, not a folder"),
        (["run", "paper", "--out", "/dev/null"], "--out /dev/null is a device or special file, not a folder"),
        (["run", "paper", "--out", "afile/deeper"], f"--out afile/deeper cannot be made: {tmp_path}/afile is a file"),
        (["reproduce", "--out", "afile"], "gimbal-lab reproduce: error: --out afile is a file, not a folder"),
        (["show", "--out", "afile/clip.mp4"], f"{tmp_path}/afile is a file, not a folder"),
        (["show", "--out", "adir"], "--out adir must end in .mp4 or .gif"),
        (["show", "--store", "afile"], "gimbal-lab show: error: --store afile is a file, not a folder"),
        (["show", "--store", "/dev/null"], "--store /dev/null is a device or special file, not a folder"),
        (TRACK[:-1] + ["afile"], "gimbal-lab track: error: --out afile is a file, not a folder"),
        (TRACK[:-1] + ["adir"], "--out adir: track.csv is a folder"),
        (["calibrate", "boards", "--out", "afile/cam.yaml"], f"{tmp_path}/afile is a file, not a folder"),
    ]
    for argv, message in cases:
        status, _, err = call(argv, capsys)
        assert status == 2, (argv, err)
        assert_one_line(err, message)
    Path("clip.mp4").mkdir()
    status, _, err = call(["show", "--out", "clip.mp4"], capsys)
    assert status == 2
    assert_one_line(err, "--out clip.mp4 is a folder; give a file name")
    Path("results").write_text("not a folder")  # where show's clip goes without --out
    status, _, err = call(["show"], capsys)
    assert status == 2
    assert_one_line(err, "gimbal-lab show: error: the clip results/show/sphere_default_circular_seed0.mp4 cannot be "
                         f"written: {tmp_path}/results is a file, not a folder")
    assert sorted(os.listdir(tmp_path)) == ["adir", "afile", "clip.mp4", "results", "tiny.toml"]  # no store, no log


@pytest.mark.parametrize("foreign", ["paper/my_notes.txt", "paper/figures/extra.png", "paper/thesis.tex"])
def test_a_report_folder_holding_foreign_files_is_refused_and_left_alone(foreign, capsys, tmp_path, no_runs, tiny):
    out = tmp_path / "results"
    (out / foreign).parent.mkdir(parents=True)
    (out / foreign).write_text("mine")
    status, _, err = call(["run", "paper", "--config", str(tiny), "--out", str(out), "--quiet"], capsys)
    assert status == 2
    name = foreign.split("/", 1)[1]
    assert_one_line(err, f"the report folder {out / 'paper'} holds {name}, which gimbal-lab did not write")
    assert (out / foreign).read_text() == "mine"
    assert sorted(p.relative_to(out).as_posix() for p in out.rglob("*") if p.is_file()) == [foreign]


# ------------------------------------------------------------------------------------------------
# failures while working: exit 1, one line
# ------------------------------------------------------------------------------------------------
def test_a_read_only_store_is_one_line(capsys):
    from test_outputs import unwritable

    shared = Path("/tmp") / f"gimbal-cli-{os.getpid()}"
    shared.mkdir()
    try:
        shared.chmod(0o777)  # the output folder is the user's; only its store is read-only
        (shared / "tiny.toml").write_text(TINY)
        store = shared / "store"
        store.mkdir()
        # a store that is a file; this also imports, as root, what the command imports before it
        # opens the store (the unprivileged user cannot read the interpreter's files)
        (shared / "other").mkdir()
        (shared / "other" / "store").write_text("x")
        status, _, err = call(["run", "paper", "--config", str(shared / "tiny.toml"), "--out", str(shared / "other"),
                               "--store", str(shared / "other" / "store"), "--quiet"], capsys)
        assert status == 1, err
        assert_one_line(err, f"results store: cannot create {shared / 'other' / 'store'}: File exists")
        runner.source_hash()  # read while this process can still read every file of the package
        with unwritable(store):
            status, _, err = call(["run", "paper", "--config", str(shared / "tiny.toml"), "--out", str(shared),
                                   "--store", str(store), "--quiet"], capsys)
        assert status == 1, err
        assert_one_line(err, f"gimbal-lab run: error: results store: cannot create {store / 'runs'}: Permission denied")
    finally:
        import shutil

        shutil.rmtree(shared, ignore_errors=True)


def _stopped(exc, store_root):
    store = runner.ResultsStore(store_root)
    return exc._stopped(3, 32, store, runner._failure_message(exc, 3, 32, store))


@pytest.mark.parametrize("make", [
    lambda: runner.WorkersDied("worker processes died 3 time(s) in this sweep (last: A process in the process "
                               "pool was terminated abruptly); the runner gives up after 2 new pools of workers"),
    lambda: runner.SourceMismatch("a worker runs gimbal_lab source 1234, this sweep 5678", "1234", "5678"),
    lambda: runner.ResultMismatch("the worker returned a result of another config"),
], ids=["workers-died", "source-mismatch", "result-mismatch"])
def test_a_failed_sweep_is_one_line(make, capsys, tmp_path, monkeypatch, tiny):
    def fail(*args, store=None, **kwargs):
        raise _stopped(make(), store.root)

    monkeypatch.setattr(runner, "run", fail)
    status, _, err = call(["run", "paper", "--config", str(tiny), "--out", str(tmp_path), "--quiet"], capsys)
    assert status == 1
    assert_one_line(err, "gimbal-lab run: error: ", "3 of 32 runs are finished and kept in", "run the same command again")


def test_a_store_that_fails_mid_sweep_is_one_line(capsys, tmp_path, monkeypatch, tiny):
    def fail(*args, store=None, **kwargs):
        raise runner.StoreError(store.runs / "abc.parquet", OSError(28, "No space left on device"))

    monkeypatch.setattr(runner, "run", fail)
    status, _, err = call(["run", "paper", "--config", str(tiny), "--out", str(tmp_path), "--quiet"], capsys)
    assert status == 1
    assert_one_line(err, "results store: cannot write", "abc.parquet: No space left on device")


@pytest.mark.parametrize("cache", [True, False])
def test_ctrl_c_says_what_a_rerun_reuses(cache, capsys, tmp_path, monkeypatch, tiny):
    def interrupted(*args, store=None, **kwargs):
        raise runner.RunInterrupted(5, 32, store)

    monkeypatch.setattr(runner, "run", interrupted)
    argv = ["run", "paper", "--config", str(tiny), "--out", str(tmp_path), "--quiet"] + ([] if cache else ["--no-cache"])
    status, _, err = call(argv, capsys)
    assert status == 130
    store = runner.ResultsStore(tmp_path / "store", read=cache)
    assert_one_line(err, f"gimbal-lab run: {runner.RunInterrupted(5, 32, store)}")
    if not cache:
        assert "run the same command again to resume" not in err and "without --no-cache" in err


def test_a_ctrl_c_an_import_swallowed_stops_the_command_before_any_run(capsys, tmp_path, monkeypatch, tiny):
    """The SIGINT handler ran while the study's modules were imported, and the import caught the
    KeyboardInterrupt (as trimesh's optional imports catch every exception): the command stops
    right after, with nothing run and exit 130, instead of running the study to its end."""
    from gimbal_lab import interrupts
    from gimbal_lab.studies import cli as studies_cli

    real_load, runs = studies_cli.load, []

    def load_swallowing_a_ctrl_c(name):
        module = real_load(name)
        interrupts.note_interrupt()  # what the handler does; its exception never reaches the command
        return module

    monkeypatch.setattr(studies_cli, "load", load_swallowing_a_ctrl_c)
    monkeypatch.setattr(runner, "run", lambda *a, **k: runs.append(1) or [])
    status, _, err = call(["run", "paper", "--config", str(tiny), "--out", str(tmp_path), "--quiet"], capsys)
    assert status == 130 and runs == [] and not (tmp_path / "paper").exists()
    assert_one_line(err, "gimbal-lab run: interrupted")
    interrupts.clear()
    monkeypatch.setattr(studies_cli, "load", real_load)  # a command after it starts afresh
    status, _, err = call(["run", "--list"], capsys)
    assert status == 0


def test_sigterm_stops_a_sweep_like_ctrl_c_keeps_its_runs_and_exits_143(capsys, tmp_path, monkeypatch, tiny):
    """SIGTERM lands as the third run of a sweep in this process starts: the two finished runs are
    stored, the line says what a rerun reuses, the exit status is 143, and the handler the
    process had before is back."""
    import signal

    computed, real = [], runner._run_one

    def run_one(config, *args, **kwargs):
        if len(computed) == 2:
            os.kill(os.getpid(), signal.SIGTERM)
        computed.append(config)
        return real(config, *args, **kwargs)

    monkeypatch.setattr(runner, "_run_one", run_one)
    before = signal.getsignal(signal.SIGTERM)
    status, _, err = call(["run", "paper", "--config", str(tiny), "--out", str(tmp_path), "--quiet", "--jobs", "1"],
                          capsys)
    store = runner.ResultsStore(tmp_path / "store")
    assert status == 143 == cli.EXIT_TERMINATED
    assert_one_line(err, f"gimbal-lab run: SIGTERM: {runner.RunInterrupted(2, 48, store)}")
    assert len(list((tmp_path / "store").rglob("*.parquet"))) == 2 and len(computed) == 2
    assert signal.getsignal(signal.SIGTERM) is before


def test_unexpected_errors_are_one_line_and_debug_shows_the_traceback(capsys, tmp_path, monkeypatch, tiny):
    def boom(*args, **kwargs):
        raise RuntimeError("boom\nwith a second line")

    monkeypatch.setattr(runner, "run", boom)
    argv = ["run", "paper", "--config", str(tiny), "--out", str(tmp_path), "--quiet"]
    status, _, err = call(argv, capsys)
    assert status == 1
    assert_one_line(err, "gimbal-lab run: error: RuntimeError: boom with a second line",
                    "run again with gimbal-lab --debug")
    with pytest.raises(RuntimeError, match="boom"):
        cli.main(["--debug"] + argv)


def test_debug_shows_the_traceback_to_a_user(tmp_path):
    """As a user runs it: an unexpected error is one line, and a traceback only with --debug."""
    code = ("import sys\nfrom gimbal_lab import cli, runner\n"
            "def boom(*a, **k):\n    raise RuntimeError('boom')\n"
            "runner.run = boom\nsys.exit(cli.main(sys.argv[1:]))")
    (tmp_path / "tiny.toml").write_text(TINY)
    argv = ["run", "paper", "--config", str(tmp_path / "tiny.toml"), "--out", str(tmp_path / "out"), "--quiet"]
    plain = subprocess.run([sys.executable, "-c", code, *argv], capture_output=True, text=True, timeout=120)
    debug = subprocess.run([sys.executable, "-c", code, "--debug", *argv], capture_output=True, text=True, timeout=120)
    assert plain.returncode == 1 and "Traceback" not in plain.stderr and "RuntimeError: boom" in plain.stderr
    assert debug.returncode == 1 and "Traceback (most recent call last)" in debug.stderr


# ------------------------------------------------------------------------------------------------
# a real run: only its own files, stale ones kept and named
# ------------------------------------------------------------------------------------------------
def test_run_paper_writes_the_whole_report_a_rerun_the_same_bytes_and_replaces_only_its_own_files(
        capsys, tmp_path, monkeypatch, tiny):
    """The whole 16-cell grid and the 8 known-lens cells, 2 replicates of 2 revolutions of 9
    frames: the report's tables, claims, figures, clips and metadata, and the terminal's summary;
    a rerun over the stored runs computes none, says so first, and leaves every report file
    byte-identical (the pipelines' CPU costs are read from the store, not timed again); a rerun
    without clips replaces only the files it writes and names the ones it kept. The costs are
    timed in one pass, not the least of 5: the checks hold for any number of passes (their values
    and the repeats have their own tests in test_studies_paper)."""
    import pandas as pd

    monkeypatch.setattr("gimbal_lab.studies._params.COST_REPEATS", 1)
    out = tmp_path / "results"
    argv = ["run", "paper", "--config", str(tiny), "--out", str(out), "--quiet", "--jobs", "2"]
    status, stdout, err = call(argv, capsys)
    assert status == 0, err
    report = out / "paper"
    for name in ("summary.csv", "replicates.parquet", "frames.parquet", "verdicts.csv", "claims.md", "study.json",
                 "pipelines.csv", "pipeline_summary.csv", "figures/pipelines_error_vs_cost.png",
                 "figures/fig11_sphere_error.png", "figures/fig14_aruco_xyz_active.svg", "figures/claims_forest.png"):
        assert (report / name).stat().st_size > 0, name
    meta = json.loads((report / "study.json").read_text())
    assert meta["study"] == "paper" and meta["runs"] == 48
    assert meta["parameters"] == paper.PaperStudy(replicates=2, period_s=0.3).to_dict()
    assert len(pd.read_parquet(report / "frames.parquet")) == 48 * 18
    assert len(pd.read_csv(report / "summary.csv")) == 8 * 2 + 8  # the sphere's two localisers, the marker's one
    verdicts = pd.read_csv(report / "verdicts.csv")
    # 29 of the paper and A7, BP1 and BP2 for 2 targets × 2 distortions × 2 trajectories
    assert len(verdicts) == 29 + 16 and {"p_value", "p_holm", "verdict_holm"} <= set(verdicts.columns)
    pipes = pd.read_csv(report / "pipeline_summary.csv")
    assert len(pipes) == 8 * 3 and (pipes["cost_ms"] > 0).all()
    # active (best) and best passive run the same estimator on the same frames: one measurement
    same = pipes[pipes.pipeline != "active (paper)"].groupby(["target", "distortion", "trajectory"])["cost_ms"]
    assert (same.nunique() == 1).all()

    manifest = json.loads((report / MANIFEST).read_text())["files"]
    written = sorted(p.relative_to(report).as_posix() for p in report.rglob("*") if p.is_file() and p.name != MANIFEST)
    assert sorted(manifest) == written and {"clips/sphere.mp4", "clips/aruco.mp4", "claims.md"} <= set(written)
    lines = stdout.strip().splitlines()
    assert lines[0] == (f"paper: 48 runs (2 replicates per cell, 2 revolutions each): 0 stored, 48 to compute on 2 "
                        f"local processes; the store is {tmp_path / 'store'}")
    # the summary: the tally at both levels, what does not hold (at most 8 lines), claims.md's path
    failing = verdicts[verdicts.verdict != "holds"]
    assert lines[1].startswith("Of 45 conditions, at 95 % each: ") and "At the family level" in lines[1]
    assert lines[-2] == f"Claims, reasons and every table: {report / 'claims.md'}"
    assert len(lines) == 1 + 1 + (1 + min(len(failing), 8) + (len(failing) > 8) if len(failing) else 0) + 2
    assert "| id |" not in stdout and "## " not in stdout  # not the file
    assert lines[-1] == f"Wrote {len(written)} files to {report}; the per-run log is {out / 'run.log'}."
    from gimbal_lab.video import probe_video

    info = probe_video(report / "clips" / "sphere.mp4")
    assert (info.codec, info.pixel_format, info.frames) == ("h264", "yuv420p", 18)

    files = {name: (report / name).read_bytes() for name in [*written, MANIFEST]}
    status, stdout, err = call(argv, capsys)
    assert status == 0, err
    assert stdout.splitlines()[0].endswith("48 stored, 0 to compute on 2 local processes; the store is "
                                           f"{tmp_path / 'store'}")
    # every report file, and the manifest: a file written again with the same bytes keeps its record
    assert {name: (report / name).read_bytes() for name in [*written, MANIFEST]} == files

    status, stdout, err = call(argv + ["--no-clips"], capsys)
    assert status == 0, err
    assert stdout.strip().splitlines()[-1] == (
        f"Wrote {len(written) - 4} files to {report}; kept 4 file(s) of an earlier run that this one did not write "
        f"again: clips/aruco.json, clips/aruco.mp4, clips/sphere.json, clips/sphere.mp4; the per-run log is "
        f"{out / 'run.log'}.")
    reports = {n: b for n, b in files.items() if n != MANIFEST}
    assert {name: (report / name).read_bytes() for name in written} == reports
    assert [p.name for p in report.iterdir() if p.name.startswith(".")] == [MANIFEST]


# ------------------------------------------------------------------------------------------------
# frames too large to process
# ------------------------------------------------------------------------------------------------
def huge_png(path: Path, width: int, height: int) -> Path:
    """A valid greyscale PNG of ``width`` x ``height`` black pixels, compressed row by row (it never
    holds the image: a 20000 x 20000 one is 0.4 MB on disk and takes a few MB to write)."""
    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    row, z = bytes(1 + width), zlib.compressobj(9)  # filter byte 0, then black pixels
    data = b"".join(z.compress(row) for _ in range(height)) + z.flush()
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0))
                     + chunk(b"IDAT", data) + chunk(b"IEND", b""))
    return path


@pytest.mark.parametrize("width, height, in_folder, message", [
    (20000, 20000, False, "has more than 179 megapixels, more than the 40 megapixels gimbal-lab reads"),
    (20000, 20000, True, "has more than 179 megapixels, more than the 40 megapixels gimbal-lab reads"),
    (8000, 6000, False, "is 8000x6000 px (48 megapixels), more than the 40 megapixels gimbal-lab reads"),
])
def test_a_huge_image_is_refused_before_it_is_decoded(width, height, in_folder, message, tmp_path):
    """calibrate on one huge image, alone or in a folder: one line, exit 2; for 20000 x 20000 the
    process never holds the image (its peak memory stays below the decoded colour image, 3 bytes a
    pixel: 1.2 GB)."""
    folder = tmp_path / "images"
    folder.mkdir()
    image = huge_png(folder / "huge.png", width, height)
    source = folder if in_folder else image
    code = ("import resource, sys\nfrom gimbal_lab import cli\ntry:\n    status = cli.main(sys.argv[1:])\n"
            "except SystemExit as exc:\n    status = exc.code\n"
            "print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)\nsys.exit(status)")
    done = subprocess.run([sys.executable, "-c", code, "calibrate", str(source), "--out", str(tmp_path / "cam.yaml"),
                           "--no-progress"], capture_output=True, text=True, timeout=120)
    assert done.returncode == 2
    assert_one_line(done.stderr, f"gimbal-lab calibrate: error: {str(image)!r} " if width == 20000 else
                    f"gimbal-lab calibrate: error: image {str(image)!r} ", message)
    peak_bytes = 1024 * int(done.stdout.strip().splitlines()[-1])  # ru_maxrss is in KiB on Linux
    if width * height > 10 * 40_000_000:  # far above the interpreter's own 0.1-0.3 GB
        assert peak_bytes < 3 * width * height
    assert not (tmp_path / "cam.yaml").exists()


def test_ctrl_c_in_show_and_calibrate_says_nothing_was_written(capsys, tmp_path, monkeypatch):
    from gimbal_lab import realworld, show_cli

    def ctrl_c(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(show_cli, "show", ctrl_c)
    status, _, err = call(["show", "--out", "c.mp4"], capsys)
    assert status == 130
    assert_one_line(err, "gimbal-lab show: interrupted: no clip written (c.mp4 is as it was)")
    Path("boards").mkdir()
    Path("cam.yaml").write_text("the earlier calibration")
    monkeypatch.setattr(realworld, "open_frames", lambda source: [])
    monkeypatch.setattr(realworld, "calibrate", ctrl_c)
    status, _, err = call(["calibrate", "boards", "--out", "cam.yaml"], capsys)
    assert status == 130
    assert_one_line(err, "gimbal-lab calibrate: interrupted: no calibration written (cam.yaml is as it was)")
    assert Path("cam.yaml").read_text() == "the earlier calibration"


def test_show_checks_its_clip_before_the_runs(tmp_path, no_runs):
    from gimbal_lab.outputs import OutputError
    from gimbal_lab.show_cli import show

    (tmp_path / "afile").write_text("x")
    with pytest.raises(OutputError, match=f"the clip {tmp_path}/afile/c.mp4 cannot be written: {tmp_path}/afile is a file"):
        show(out=tmp_path / "afile" / "c.mp4", progress=False)
