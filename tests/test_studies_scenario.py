"""Scenario files: the grammar (every error names the file, the table, the key and what is allowed),
the configs a file builds against the studies that build the same runs, the hypotheses on hand-built
frame tables, and a scenario on a calibration file run end to end from the command line."""

import json
import math
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from gimbal_lab import stats
from gimbal_lab.config import Camera, TrackingConfig
from gimbal_lab.simulation import TrackingResult
from gimbal_lab.studies import load
from gimbal_lab.studies import moving_drone as md
from gimbal_lab.studies import paper
from gimbal_lab.studies import scenario as sc

ROOT = Path(__file__).resolve().parents[1]
SCENARIOS = ROOT / "data" / "scenarios"
CHARUCO = ROOT / "data" / "calibration" / "opencv_charuco_tutorial_640x480.yml"


def write(folder: Path, text: str, name: str = "rig.toml") -> Path:
    path = folder / name
    path.write_text(text)
    return path


@pytest.fixture
def rig(tmp_path):
    """A folder with a calibration file beside the scenario, as a user keeps them."""
    shutil.copy(CHARUCO, tmp_path / "cam.yml")
    return tmp_path


# ----------------------------------------------------------------------------------------------
# what a file builds
# ----------------------------------------------------------------------------------------------
@pytest.mark.parametrize("path", sorted(SCENARIOS.glob("*.toml")), ids=lambda p: p.name)
def test_every_shipped_scenario_builds_all_its_runs_and_states_hypotheses(path):
    scenario = sc.Scenario.from_toml(path)
    assert scenario.description and scenario.hypotheses and scenario.replicates == 10
    assert len(sc.grid(scenario)) == len(scenario.cells) * 10 == len(set(sc.grid(scenario)))


def test_the_paper_rig_is_the_paper_studys_distorted_sphere_cells():
    """Oracle: the paper study's own grid. The scenario's 4 cells × 10 replicates are exactly its
    sphere/distorted cells (same configs, so the same store keys: each reuses the other's runs)."""
    scenario = sc.Scenario.from_toml(SCENARIOS / "paper-rig.toml")
    expected = [c for c in paper.grid(paper.PaperStudy(), targets=("sphere",)) if c.camera.lens_label == "distorted"]
    assert len(sc.grid(scenario)) == 40 and set(sc.grid(scenario)) == set(expected)
    assert {c.key for c in sc.grid(scenario)} == {c.key for c in expected}


def test_the_long_lens_flight_draws_the_moving_drone_studys_flight_phases():
    scenario = sc.Scenario.from_toml(SCENARIOS / "long-lens-flight.toml")
    for c in sc.grid(scenario):
        assert c.platform.motion == "flight" and c.platform.motion_phase_s == md.flight_phase_s(c.seed)
        assert c.target.start_phase_s == paper.replicate_phase_s(c.seed, 2.0)
        assert math.degrees(c.camera.horizontal_field_rad) == pytest.approx(20.0, rel=1e-12)
    assert [c.pointing.kind for c in sc.grid(scenario)[::10]] == ["fixed", "stabilised", "paper"]


def test_a_calibration_path_is_read_relative_to_the_scenario_file_and_kept_as_numbers(rig, monkeypatch):
    (rig / "cals").mkdir()
    shutil.move(rig / "cam.yml", rig / "cals" / "cam.yml")
    path = write(rig, '[camera]\ncalibration = "cals/cam.yml"\nfps = 60.0\n'
                      '[sweep]\ncamera = ["calibration:cals/cam.yml", "ideal", "paper"]\n')
    monkeypatch.chdir(rig / "cals")  # not the scenario's folder
    scenario = sc.Scenario.from_toml(path)
    expected = Camera.from_calibration(CHARUCO, fps=60.0)
    calibrated, ideal, paper_camera = (scenario.config(cell, 0).camera for cell in scenario.cells)
    assert calibrated == expected and ideal == expected.replace(lens="none")
    assert paper_camera == Camera(lens="default", fps=60.0)
    assert sc.grid(scenario)[0].camera == expected  # [camera] calibration: the rig itself
    for config in sc.grid(scenario):  # what the store keys: numbers, never the path
        assert "cam.yml" not in json.dumps(config.to_dict())
    assert sc.Scenario(**json.loads(json.dumps(scenario.to_dict()))) == scenario  # plain data round trip


def test_levels_of_fields_shorthands_and_the_replicates_draws(rig):
    path = write(rig, '[run]\nreplicates = 3\nfirst_seed = 4\n[platform]\nmotion = "hover"\n'
                      '[sweep]\n"camera.fps" = [30, 60]\nplatform.sway.yaw_rms_rad = [0.01, 0.02]\n'
                      'pointing = ["fixed", "filter:ca"]\ntarget = ["aruco", "sphere"]\n', "ok.toml")
    with pytest.raises(ValueError, match=r"\[sweep\] cell camera.fps=30, platform.sway.yaw_rms_rad=0.01, "
                                         r"pointing=filter:ca, target=aruco: pointing 'filter' assumes a still platform"):
        sc.Scenario.from_toml(path)
    path = write(rig, path.read_text().replace('motion = "hover"', 'motion = "static"'), "ok.toml")
    scenario = sc.Scenario.from_toml(path)
    assert len(scenario.cells) == 16 and scenario.seeds == [4, 5, 6]
    cell = (("camera.fps", "60"), ("platform.sway.yaw_rms_rad", "0.02"), ("pointing", "filter:ca"),
            ("target", "aruco"))
    c = scenario.config(cell, 5)
    assert (c.camera.fps, c.platform.sway.yaw_rms_rad, c.pointing.kind, c.pointing.filter, c.target.kind, c.seed) == \
        (60.0, 0.02, "filter", "ca", "aruco", 5)
    assert c.target.start_phase_s == paper.replicate_phase_s(5, 2.0) and c.revolutions == 2.0
    assert scenario.config(cell, 5) == TrackingConfig().with_(
        camera__fps=60.0, platform__sway__yaw_rms_rad=0.02, pointing__kind="filter", pointing__filter="ca",
        target__kind="aruco", target__start_phase_s=paper.replicate_phase_s(5, 2.0), seed=5)


def test_the_command_line_replicate_count_rebuilds_the_scenario():
    scenario = sc.Scenario.from_toml(SCENARIOS / "phone-quad.toml")
    fewer = load("x.toml").Study(**{**scenario.to_dict(), "replicates": 3})  # what `run --replicates 3` does
    assert fewer.replicates == 3 and len(sc.grid(fewer)) == 4 * 3 and fewer.base == scenario.base


# ----------------------------------------------------------------------------------------------
# errors: file, table, key and what is allowed
# ----------------------------------------------------------------------------------------------
GOOD_SWEEP = '[sweep]\npointing = ["stabilised", "paper"]\n'
BAD_FILES = [
    # (file text, the error after "FILE: ")
    ('[cameras]\nfps = 30\n', r"\[cameras\]: unknown table; allowed: the tables \[run\], \[camera\]"),
    ('name = "x"\n', r"\[name\]: unknown key; allowed: .*and the key description"),
    ('description = 3\n', r"\[description\]: 3 is not text; allowed: a string"),
    ('sweep = 3\n', r"\[sweep\]: is 3, not a table; allowed: \[sweep\] as a table"),
    ('[run]\nreplicate = 3\n', r"\[run\] replicate: unknown key; allowed: replicates, first_seed, revolutions"),
    ('[run]\nreplicates = 1\n', r"\[run\] replicates: replicates must be >= 2 and <= 1000, got 1; allowed: an integer"),
    ('[run]\nreplicates = 2.5\n', r"\[run\] replicates: replicates must be an integer"),
    ('[run]\nrevolutions = 1.5\n', r"\[run\] revolutions: revolutions must be >= 2 .*; allowed: a number >= 2"),
    ('[run]\nfirst_seed = -1\n', r"\[run\] first_seed: first_seed must be >= 0"),
    ('[camera]\nfps = -1\n', r"\[camera\] camera.fps must be > 0, got -1"),
    ('[camera]\nfsp = 30\n', r"\[camera\] unknown camera key\(s\): fsp \(allowed: width, height, hfov_rad"),
    ('[camera]\nblur = "smooth"\n', r"\[camera\] camera.blur must be one of \('auto', 'fast', 'subframes', 'none'\)"),
    ('[camera]\ncalibration = "missing.yml"\n',
     r"\[camera\] calibration: calibration 'missing.yml': no such calibration file.*; allowed: an OpenCV FileStorage"),
    ('[camera]\ncalibration = 3\n', r"\[camera\] calibration: 3 is not a path; allowed: a calibration file's path"),
    ('[camera]\ncalibration = "cam.yml"\nhfov_rad = 1.0\n',
     r"\[camera\] hfov_rad: the calibration file gives it; allowed: the camera's other fields"),
    ('[camera]\ncalibration = "cam.yml"\nlens = "none"\n', r"\[camera\] lens: the calibration file gives it"),
    ('[camera]\ncalibration = "cam.yml"\nexposure_s = 0.5\n', r"\[camera\] camera.exposure_s must be >= 0 and <= 0.0333"),
    ('[target]\nstart_phase_s = 0.5\n', r"\[target\] start_phase_s: the target's start phase is drawn per replicate"),
    ('[target]\nkind = "cube"\n', r"\[target\] target.kind must be one of \('sphere', 'aruco'\)"),
    ('[platform]\nmotion_phase_s = 1.0\n', r"\[platform\] motion_phase_s: where the flight starts is drawn per replicate"),
    ('[platform]\nsway = {yaw_rms = 1}\n', r"\[platform\] .*platform.sway.*yaw_rms"),
    ('[pointing]\nkind = "predictive"\n[platform]\nmotion = "hover"\n',
     r"the rig's part tables: pointing 'predictive' assumes a still platform; platform.motion is 'hover'"),
    ('[sweep]\npointing = ["stabilised", "pape"]\n',
     r"\[sweep\] pointing: level 'pape' is not a named pointing level; allowed: fixed, stabilised, paper, predictive, "
     r"filter, filter:cv, filter:ca, filter:imm"),
    ('[sweep]\ncamera = ["ideal", "wide"]\n', r"\[sweep\] camera: level 'wide' .*; allowed: ideal, paper, calibration:FILE"),
    ('[sweep]\ncamera = ["ideal", "calibration:missing.yml"]\n',
     r"\[sweep\] camera: calibration 'missing.yml': no such calibration file"),
    ('[sweep]\npointing = ["paper"]\n', r"\[sweep\] pointing: \['paper'\] is not a list of levels; allowed: a list of at "
                                        r"least two levels"),
    ('[sweep]\npointing = "paper"\n', r"\[sweep\] pointing: 'paper' is not a list of levels"),
    ('[sweep]\npointing = ["paper", "paper"]\n', r"\[sweep\] pointing: level 'paper' is given twice; allowed: distinct"),
    ('[sweep]\n"camera.fps" = [30, 30.0]\n', r"\[sweep\] camera.fps: level 30 is given twice"),
    ('[sweep]\ngimbal = ["a", "b"]\n', r"\[sweep\] gimbal: 'gimbal' has no named levels; allowed: named levels for "
                                       r"camera, platform, target, pointing, or part.field"),
    ('[sweep]\nlens = ["a", "b"]\n', r"\[sweep\] lens: 'lens' is not a part; allowed: named levels"),
    ('[sweep]\ncamera.fsp = [30, 60]\n', r"\[sweep\] camera.fsp: camera has no field 'fsp'; allowed: width, height"),
    ('[sweep]\n"lens.k1" = [0.1, 0.2]\n', r"\[sweep\] lens.k1: 'lens' is not a part; allowed: a part \(camera, gimbal"),
    ('[sweep]\n"camera.fps.x" = [1, 2]\n', r"\[sweep\] camera.fps.x: camera.fps has no fields; allowed: a field"),
    ('[sweep]\n"platform.sway.yaw" = [1, 2]\n', r"\[sweep\] platform.sway.yaw: platform.sway has no field 'yaw'; "
                                                r"allowed: roll_pitch_rms_rad, yaw_rms_rad"),
    ('[sweep]\n"target.start_phase_s" = [0.1, 0.2]\n',
     r"\[sweep\] target.start_phase_s: the target's start phase is drawn per replicate"),
    ('[sweep]\ncamera = ["ideal", "paper"]\n"camera.lens" = ["none", "default"]\n',
     r"\[sweep\] camera.lens: sets camera.lens, as camera does; allowed: factors that set different fields"),
    ('[sweep]\n"camera.fps" = [30, -1]\n', r"\[sweep\] cell camera.fps=-1: camera.fps must be > 0, got -1"),
    ('[platform]\nmotion = "vibration"\n[sweep]\npointing = ["stabilised", "predictive"]\n',
     r"\[sweep\] cell pointing=predictive: pointing 'predictive' assumes a still platform; platform.motion is "
     r"'vibration'"),
    (GOOD_SWEEP + 'compare = 3\n', r"\[sweep\] compare: 3 is not a list of levels"),  # a key after [sweep] is its own
    (GOOD_SWEEP + '[compare]\nH1 = "paper < stabilised"\n',
     r"\[compare.H1\]: is 'paper < stabilised', not a table; allowed: a table with a, b"),
    (GOOD_SWEEP + '[compare.H1]\nb = "stabilised"\n', r"\[compare.H1\] a: missing; allowed: a level of a \[sweep\] factor"),
    (GOOD_SWEEP + '[compare.H1]\na = "paper"\n', r"\[compare.H1\] b: missing"),
    (GOOD_SWEEP + '[compare.H1]\na = ["paper"]\nb = "stabilised"\n', r"\[compare.H1\] a: \['paper'\] is not a level name"),
    (GOOD_SWEEP + '[compare.H1]\na = "paper"\nb = "paper"\n',
     r"\[compare.H1\] b: the same level as a \('paper'\); allowed: another level"),
    (GOOD_SWEEP + '[compare.H1]\na = "pape"\nb = "stabilised"\n',
     r"\[compare.H1\] factor: no factor has both levels \('pape', 'stabilised'\); allowed: factor = one of pointing"),
    (GOOD_SWEEP + '[compare.H1]\nfactor = "pointing"\na = "pape"\nb = "stabilised"\n',
     r"\[compare.H1\] a: 'pape' is not a level of pointing; allowed: stabilised, paper"),
    (GOOD_SWEEP + '[compare.H1]\nfactor = "platform"\na = "paper"\nb = "stabilised"\n',
     r"\[compare.H1\] factor: 'platform' is not a \[sweep\] factor; allowed: pointing"),
    ('[sweep]\npointing = ["stabilised", "paper"]\n"target.kind" = ["stabilised", "paper"]\n'
     '[compare.H1]\na = "paper"\nb = "stabilised"\n',
     r"\[compare.H1\] factor: factors pointing, target.kind all have both"),
    (GOOD_SWEEP + '[compare.H1]\na = "paper"\nb = "stabilised"\nkind = "greater"\n',
     r"\[compare.H1\] kind: 'greater'; allowed: less, non_inferior, equivalent"),
    (GOOD_SWEEP + '[compare.H1]\na = "paper"\nb = "stabilised"\nmetric = "rmse"\n',
     r"\[compare.H1\] metric: 'rmse'; allowed: error \(m\), missed \(fraction\), offset \(px\)"),
    (GOOD_SWEEP + '[compare.H1]\na = "paper"\nb = "stabilised"\nfloor = -1\n',
     r"\[compare.H1\] floor: floor must be > 0, got -1; allowed: a number > 0 in the metric's unit \(m\)"),
    (GOOD_SWEEP + '[compare.H1]\na = "paper"\nb = "stabilised"\nfloor = "1 mm"\n', r"\[compare.H1\] floor: floor must be a number"),
    (GOOD_SWEEP + '[compare.H1]\na = "paper"\nb = "stabilised"\nkind = "equivalent"\nfloor = 0.01\n',
     r"\[compare.H1\] floor: an equivalence has its ±20 % margin, no floor"),
    (GOOD_SWEEP + '[compare.H1]\na = "paper"\nb = "stabilised"\ndelta = 0.01\n',
     r"\[compare.H1\] delta: unknown key; allowed: factor, a, b, kind, metric, floor, statement"),
    (GOOD_SWEEP + '[compare.H1]\na = "paper"\nb = "stabilised"\nstatement = 3\n', r"\[compare.H1\] statement: 3 is not text"),
    ('[compare.H1]\na = "paper"\nb = "stabilised"\n', r"\[compare.H1\] factor: no \[sweep\] table, so 'paper' and "
     r"'stabilised' are levels of no factor; allowed: a \[sweep\] table with a factor that has both levels$"),
    ('[run\n', r"not valid TOML"),
]


@pytest.mark.parametrize("text, message", BAD_FILES, ids=[f"{i:02d}" for i in range(len(BAD_FILES))])
def test_every_error_names_the_file_the_table_the_key_and_what_is_allowed(rig, text, message):
    path = write(rig, text)
    with pytest.raises((ValueError, TypeError)) as info:
        sc.Scenario.from_toml(path)
    assert str(info.value).startswith(f"{path}: "), str(info.value)
    assert len(str(info.value).splitlines()) == 1
    assert __import__("re").search(message, str(info.value)), str(info.value)


def test_a_missing_file_is_named():
    with pytest.raises(FileNotFoundError, match="no such scenario file: 'nowhere.toml'"):
        sc.Scenario.from_toml("nowhere.toml")


def test_nothing_runs_or_is_stored_before_the_whole_file_validates(rig):
    """The error sits in the last cell only (a latency of 4 frames in a run of 4: 2 revolutions of
    0.4 s at 5 frames/s): only building every cell's config finds it. The command stops with one
    line and exit status 2, and neither the output nor the store exists."""
    from gimbal_lab import cli

    path = write(rig, '[run]\nreplicates = 2\n[camera]\nfps = 5.0\n[target]\nperiod_s = 0.4\n'
                      '[sweep]\npointing = ["stabilised", "paper"]\n"camera.latency_frames" = [1, 4]\n')
    with pytest.raises(ValueError, match=r"\[sweep\] cell pointing=stabilised, camera.latency_frames=4: "
                                         r"camera.latency_frames=4 must be fewer than the run's frames"):
        sc.Scenario.from_toml(path)
    out = rig / "out"
    with pytest.raises(SystemExit) as info:
        cli.main(["run", str(path), "--out", str(out), "--quiet"])
    assert info.value.code == 2 and not out.exists()


def test_resolved_hypotheses_are_checked_against_the_factors():
    scenario = sc.Scenario.from_toml(SCENARIOS / "phone-quad.toml")
    d = scenario.to_dict()
    for change, match in ((dict(factor="camera"), r"\[compare.H1\] factor: 'camera' is not a \[sweep\] factor"),
                          (dict(a="predictive"), r"\[compare.H1\] a: 'predictive' is not a level of pointing"),
                          (dict(metric="rmse"), r"\[compare.H1\] metric")):
        bad = {**d, "hypotheses": {**d["hypotheses"], "H1": {**d["hypotheses"]["H1"], **change}}}
        with pytest.raises(ValueError, match=match):
            sc.Scenario(**bad)


# ----------------------------------------------------------------------------------------------
# hypotheses on hand-built frame tables
# ----------------------------------------------------------------------------------------------
def fake_result(config, detected, error_m, offset_px=10.0):
    """A run's frame table with the columns the scenario reads: the measured revolution's frames
    get ``detected`` and ``error_m`` (arrays), the acquisition revolution detects everything."""
    n = config.n_frames
    first = round(config.frames_per_revolution)
    det = np.ones(n, bool)
    err = np.full(n, 0.5)
    det[first:], err[first:] = detected, error_m
    frames = pd.DataFrame({"frame": np.arange(n), "t_s": np.arange(n) / config.camera.fps,
                           "t_mid_s": np.arange(n) / config.camera.fps, "revolution": np.arange(n) // first,
                           "detected": det, "abs_error_m": np.where(det, err, np.nan),
                           "offset_px": np.full(n, offset_px), "true_offset_px": np.full(n, offset_px),
                           "streak_px": np.zeros(n)})
    return TrackingResult(config, frames)


@pytest.fixture
def two_levels(tmp_path):
    path = write(tmp_path, '[run]\nreplicates = 4\n[target]\nperiod_s = 0.4\n'
                           '[sweep]\n"camera.noise_std" = [1, 3]\npointing = ["stabilised", "paper"]\n'
                           '[compare.E]\na = "paper"\nb = "stabilised"\n'
                           '[compare.M]\na = "paper"\nb = "stabilised"\nmetric = "missed"\nkind = "non_inferior"\n'
                           '[compare.O]\na = "paper"\nb = "stabilised"\nmetric = "offset"\nkind = "equivalent"\n')
    return sc.Scenario.from_toml(path)


def test_errors_are_compared_on_the_frames_both_runs_detected(two_levels):
    """Passive: misses every other frame, 2.1 mm where it sees the target. Active: detects every
    frame, 1 mm on the frames the passive run saw and 5 mm on the others. On the frames both
    detected: 1 vs 2.1 mm per replicate (δ = 1 mm: holds). Each on its own detections it would be
    3 vs 2.1 mm, the opposite."""
    s = two_levels
    results = []
    for cell, seed, config in s.runs():
        m = round(config.frames_per_revolution)
        jitter = 1e-5 * (seed % 2)  # a spread, so the interval is an interval
        seen = np.arange(m) % 2 == 0
        if config.pointing.active:
            results.append(fake_result(config, np.ones(m, bool), np.where(seen, 1e-3, 5e-3) + jitter, offset_px=5.0))
        else:
            results.append(fake_result(config, seen, np.full(m, 2.1e-3), offset_px=5.0 + jitter))
    verdicts = sc.check_hypotheses(s, results)
    e = verdicts[verdicts.id == "E"]
    assert list(e.condition) == ["camera.noise_std=1", "camera.noise_std=3"]
    assert np.allclose(e.mean_a, 1e-3 + 0.5e-5) and np.allclose(e.mean_b, 2.1e-3)
    assert (e.verdict == stats.HOLDS).all() and (e.n == 4).all()
    m = verdicts[verdicts.id == "M"]  # active misses nothing, passive half: far better than the margin
    assert np.allclose(m.mean_a, 0.0) and np.allclose(m.mean_b, 0.5) and (m.verdict == stats.HOLDS).all()
    assert (m.kind == "non-inferior").all()
    o = verdicts[verdicts.id == "O"]  # offsets equal within 1e-5 px: equivalent
    assert (o.verdict == stats.HOLDS).all() and (o.kind == "equivalent").all()
    # one family, Holm's adjustment beside the verdict
    expected = stats.holm(verdicts.drop(columns=["p_holm", "verdict_holm"]))
    pd.testing.assert_frame_equal(verdicts, expected)
    assert len(verdicts) == 6


def test_a_replicate_without_common_detections_drops_out_of_its_pair(two_levels):
    s = two_levels
    results = []
    for cell, seed, config in s.runs():
        m = round(config.frames_per_revolution)
        seen = np.zeros(m, bool) if (seed < 3 and not config.pointing.active) else np.ones(m, bool)
        results.append(fake_result(config, seen, np.full(m, 1e-3 * (1 + seed))))
    e = sc.check_hypotheses(s, results).query("id == 'E'")
    assert (e.n == 1).all() and (e.verdict == stats.INCONCLUSIVE).all() and e.low.isna().all()
    o = sc.check_hypotheses(s, results).query("id == 'O'")
    assert (o.n == 4).all()  # the offset is truth: every frame has one


def test_the_replicate_table_and_summary_follow_the_cells(two_levels):
    s = two_levels
    results = [fake_result(c, np.ones(round(c.frames_per_revolution), bool),
                           np.full(round(c.frames_per_revolution), 1e-3 * (1 + seed)))
               for cell, seed, c in s.runs()]
    table = sc.replicate_table(s, results)
    assert list(table.columns[:3]) == ["camera.noise_std", "pointing", "seed"] and len(table) == 16
    summary = sc.summary_table(table, s)
    assert list(summary.label) == [sc._cell_label(cell) for cell in s.cells]
    mean, low, high = stats.t_interval(1e-3 * (1 + np.arange(4)))
    assert np.allclose(summary.mean_abs_error_m, mean) and np.allclose(summary.ci_low_m, low)
    with pytest.raises(ValueError, match="is not the run of"):
        sc.replicate_table(s, results[::-1])


def test_a_scenario_without_hypotheses_is_titled_by_its_cells(tmp_path, two_levels):
    """claims.md's title says "hypotheses, measured" only when there are hypotheses."""
    plain = sc.Scenario.from_toml(write(tmp_path, '[run]\nreplicates = 2\n[target]\nperiod_s = 0.4\n'
                                                  '[sweep]\npointing = ["stabilised", "paper"]\n', "plain.toml"))
    for s, title in ((plain, "# Scenario plain: the cells, measured (no hypotheses)"),
                     (two_levels, "# Scenario rig: hypotheses, measured")):
        results = [fake_result(c, np.ones(round(c.frames_per_revolution), bool),
                               np.full(round(c.frames_per_revolution), 1e-3 * (1 + seed))) for cell, seed, c in s.runs()]
        text = sc.hypotheses_markdown(sc.check_hypotheses(s, results), sc.summary_table(sc.replicate_table(s, results), s), s)
        assert text.splitlines()[0] == title


# ----------------------------------------------------------------------------------------------
# the command line
# ----------------------------------------------------------------------------------------------
def test_run_list_shows_the_studies_and_the_example_scenarios():
    done = subprocess.run([sys.executable, "-m", "gimbal_lab.cli", "run", "--list"], capture_output=True, text=True,
                          cwd=ROOT, check=True)
    lines = done.stdout.splitlines()
    from gimbal_lab.studies import STUDIES

    for study in STUDIES:
        assert any(line.startswith(study + " ") for line in lines), done.stdout
    for name in ("paper-rig", "phone-quad", "long-lens-flight"):
        description = sc.tomllib.loads((SCENARIOS / f"{name}.toml").read_text())["description"]
        assert f"data/scenarios/{name}.toml  {description}" in lines, done.stdout
    assert len(lines) == len(STUDIES) + len(list(SCENARIOS.glob("*.toml")))


def test_a_scenario_on_a_calibration_file_runs_end_to_end_from_the_command_line(rig):
    """The real command in a fresh process: 2 cells × 2 replicates of 2 revolutions at 10 frames per
    revolution, a camera from the calibration file beside the scenario. Checks the report's files,
    the verdicts at both levels, the clip, and the store holding the calibration's numbers."""
    path = write(rig, 'description = "tiny rig"\n[run]\nreplicates = 2\n'
                      '[camera]\ncalibration = "cam.yml"\nfps = 10.0\n[target]\nperiod_s = 1.0\n'
                      '[sweep]\npointing = ["stabilised", "paper"]\n'
                      '[compare.H1]\na = "paper"\nb = "stabilised"\n')
    out = rig / "out"
    env = {**os.environ, "PYOPENGL_PLATFORM": "egl", "LP_NUM_THREADS": "1"}
    done = subprocess.run([sys.executable, "-m", "gimbal_lab.cli", "run", str(path), "--out", str(out), "--jobs", "1",
                           "--store", str(out / "store"), "--quiet"], capture_output=True, text=True, env=env, cwd=rig,
                          timeout=600)
    assert done.returncode == 0, done.stderr
    assert f"{path}: 4 runs (2 replicates per cell, 2 revolutions each): 0 stored, 4 to compute" in done.stdout
    report = out / "rig"
    for name in ("claims.md", "summary.csv", "replicates.csv", "verdicts.csv", "study.json", "scenario.toml",
                 "figures/cells.png", "figures/hypotheses_forest.png", "clips/passive-active.mp4"):
        assert (report / name).is_file(), name
    verdicts = pd.read_csv(report / "verdicts.csv")
    assert list(verdicts.condition) == ["all"] and {"p_value", "p_holm", "verdict_holm"} <= set(verdicts.columns)
    assert verdicts.verdict[0] in stats.VERDICTS and verdicts.verdict_holm[0] in stats.VERDICTS
    claims = (report / "claims.md").read_text()
    assert "tiny rig" in claims and "| p (Holm) | verdict (family) |" in claims
    assert "Of 1 conditions, at 95 % each: " in done.stdout and f"every table: {report / 'claims.md'}" in done.stdout
    assert "| p (Holm) |" not in done.stdout  # the terminal gets the summary, not the file
    assert (report / "scenario.toml").read_text() == path.read_text()
    sidecars = list((out / "store").rglob("*.json"))
    assert len(sidecars) == 4
    K = Camera.from_calibration(CHARUCO).intrinsics
    for sidecar in sidecars:
        camera = json.loads(sidecar.read_text())["config"]["camera"]
        assert camera["calibration"] == {"fx": K.fx, "fy": K.fy, "cx": K.cx, "cy": K.cy, "width": 640, "height": 480}
        assert "cam.yml" not in sidecar.read_text()
