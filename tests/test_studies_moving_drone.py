"""The moving-drone study: its grid and draws, its replicate table on hand-built frame tables, and
its hypotheses on hand-built replicate tables, one case per outcome."""

import itertools
import math

import numpy as np
import pandas as pd
import pytest

from gimbal_lab import stats
from gimbal_lab.platform import WaypointFlight
from gimbal_lab.simulation import TrackingResult
from gimbal_lab.studies import _params, load
from gimbal_lab.studies import moving_drone as md
from gimbal_lab.studies.paper import replicate_phase_s

SEEDS = range(6)
JITTER = np.array([-1, 1, -1, 1, -1, 1]) * 1e-4  # ±0.1 mm: designed effects stay far outside their intervals


# ----------------------------------------------------------------------------------------------
# grid and parameters
# ----------------------------------------------------------------------------------------------
def test_grid_is_36_cells_times_replicates_with_shared_draws():
    study = md.MovingDroneStudy(replicates=3, first_seed=5)
    configs = md.grid(study)
    assert len(configs) == 36 * 3
    cells = {(c.target.kind, c.platform.motion, c.pointing.mount, "rolling" if c.camera.readout_s else "global")
             for c in configs}
    assert cells == set(itertools.product(md.TARGETS, md.MOTIONS, md.MOUNTS, md.SHUTTERS))
    for c in configs:
        assert (c.camera.exposure_s, c.camera.blur, c.target.trajectory) == (1 / 60, "fast", "circular")
        assert c.camera.readout_s in (0.0, 0.020)
        assert c.gimbal.gyro_noise_rad_s_rthz == pytest.approx(math.radians(0.005), rel=1e-12)
        assert c.pointing.kind == {"active": "paper"}.get(c.pointing.mount, c.pointing.mount)  # paper's loop if active
        assert c.target.start_phase_s == replicate_phase_s(c.seed, 2.0)
        assert c.platform.motion_phase_s == (md.flight_phase_s(c.seed) if c.platform.motion == "flight" else 0.0)
    assert sorted({c.seed for c in configs}) == [5, 6, 7]
    phases = [md.flight_phase_s(s) for s in range(200)]
    assert 0.0 <= min(phases) and max(phases) < WaypointFlight().period_s == 10.0
    assert len(set(phases)) == 200 and md.flight_phase_s(3) == md.flight_phase_s(3)


def test_the_same_seed_is_the_same_body_in_every_cell():
    study = md.MovingDroneStudy(replicates=2)
    bodies = [study.config("sphere", "vibration", m, s, 1).body for m in md.MOUNTS for s in md.SHUTTERS]
    bodies += [study.config("aruco", "vibration", "fixed", "global", 1).body]
    t = np.linspace(0.0, 1.0, 7)
    poses = [b.T_world_body(t) for b in bodies]
    assert all(np.array_equal(p, poses[0]) for p in poses)
    other = study.config("sphere", "vibration", "fixed", "global", 2).body.T_world_body(t)
    assert not np.allclose(other, poses[0])


@pytest.mark.parametrize("kwargs, field", [
    (dict(replicates=1), "replicates"), (dict(revolutions=1.5), "revolutions"), (dict(exposure_s=0.0), "exposure_s"),
    (dict(exposure_s=0.05), "exposure_s"), (dict(readout_s=-0.01), "readout_s"), (dict(fps=-1), "fps"),
    (dict(aruco_refinement="best"), "aruco_refinement"),
])
def test_bad_parameters_name_the_field(kwargs, field):
    with pytest.raises(ValueError, match=field):
        md.MovingDroneStudy(**kwargs)


@pytest.mark.parametrize("args, name", [
    (("cube", "hover", "fixed", "global", 0), "target"), (("sphere", "sway", "fixed", "global", 0), "motion"),
    (("sphere", "hover", "handheld", "global", 0), "mount"), (("sphere", "hover", "fixed", "slow", 0), "shutter"),
])
def test_bad_cell_names_are_clear_errors(args, name):
    with pytest.raises(ValueError, match=name):
        md.MovingDroneStudy(replicates=2).config(*args)


def test_config_from_toml_and_the_shipped_file_is_the_default(tmp_path):
    path = tmp_path / "md.toml"
    path.write_text('[moving-drone]\nreplicates = 4\nreadout_s = 0.03\n')
    study = md.MovingDroneStudy.from_toml(path)
    assert (study.replicates, study.readout_s, study.seeds) == (4, 0.03, [0, 1, 2, 3])
    path.write_text('[moving-drone]\nshutter = "rolling"\n')
    with pytest.raises(ValueError, match="unknown key.*shutter"):
        md.MovingDroneStudy.from_toml(path)
    from pathlib import Path

    shipped = Path(__file__).parent.parent / "data" / "studies" / "moving-drone.toml"
    assert md.MovingDroneStudy.from_toml(shipped) == md.MovingDroneStudy()
    assert load("moving-drone") is md and md.Study is md.MovingDroneStudy


@pytest.mark.parametrize("text, expected", [("", 10), ("3", 3), (" 12 ", 12)])
def test_replicates_from_the_environment(monkeypatch, text, expected):
    monkeypatch.setenv(_params.REPLICATES_ENV, text)
    assert _params.replicates_from_env() == expected


@pytest.mark.parametrize("text", ["1", "three", "2.5", "-4"])
def test_bad_replicates_in_the_environment_name_the_variable(monkeypatch, text):
    monkeypatch.setenv(_params.REPLICATES_ENV, text)
    with pytest.raises(ValueError, match=_params.REPLICATES_ENV):
        _params.replicates_from_env()


# ----------------------------------------------------------------------------------------------
# replicate table on hand-built runs
# ----------------------------------------------------------------------------------------------
def fake_run(mount, detected, errors, streaks, seed=0, shutter="global", motion="hover", target="sphere"):
    """A run of ``len(detected)`` frames per revolution × 2 revolutions: the first revolution is
    acquisition (its frames are all detected with a 1 m error, which must not count)."""
    study = md.MovingDroneStudy(replicates=2, fps=3.0, period_s=2.0)  # 6 frames per revolution
    config = study.config(target, motion, mount, shutter, seed)
    n = int(config.frames_per_revolution)
    assert len(detected) == n
    frames = pd.DataFrame({
        "frame": np.arange(2 * n),
        "t_s": np.arange(2 * n) / config.camera.fps,
        "t_mid_s": np.arange(2 * n) / config.camera.fps,
        "detected": np.r_[np.ones(n, bool), detected],
        "abs_error_m": np.r_[np.ones(n), np.where(detected, errors, np.nan)],
        "streak_px": np.r_[np.full(n, 99.0), streaks],
        "cam_turn_deg": np.r_[np.zeros(n), np.full(n, 0.5)],
        "true_offset_px": np.r_[np.zeros(n), np.full(n, 10.0)],
        "offset_px": np.r_[np.full(n, 100.0), np.full(n, 10.0)],
    })
    return TrackingResult(config=config, frames=frames)


def test_common_frames_are_those_every_mount_detected():
    d = {"fixed": [1, 1, 0, 1, 0, 1], "stabilised": [1, 1, 1, 1, 0, 0], "active": [1, 1, 1, 1, 1, 1]}
    errors = {"fixed": [0.1, 0.2, 0.3, 0.4, 0.5, 0.6], "stabilised": [0.01, 0.02, 0.03, 0.04, 0.05, 0.06],
              "active": [0.001, 0.002, 0.003, 0.004, 0.005, 0.006]}
    streaks = {"fixed": [10, 12, 14, 10, 12, 14], "stabilised": [5] * 6, "active": [1, 2, 1, 2, 1, 2]}
    runs = [fake_run(m, np.array(d[m], bool), np.array(errors[m]), np.array(streaks[m], float)) for m in md.MOUNTS]
    table = md.replicate_table(runs).set_index("mount")
    # common: frames 0, 1, 3 (by hand)
    assert table.loc["fixed", "common_rate"] == pytest.approx(0.5)
    assert table.loc["fixed", "common_abs_error_m"] == pytest.approx((0.1 + 0.2 + 0.4) / 3, abs=1e-15)
    assert table.loc["stabilised", "common_abs_error_m"] == pytest.approx((0.01 + 0.02 + 0.04) / 3, abs=1e-15)
    assert table.loc["active", "common_abs_error_m"] == pytest.approx(0.007 / 3, abs=1e-15)
    # own detections
    assert table.loc["fixed", "detection_rate"] == pytest.approx(4 / 6)
    assert table.loc["fixed", "mean_abs_error_m"] == pytest.approx((0.1 + 0.2 + 0.4 + 0.6) / 4, abs=1e-15)
    assert table.loc["stabilised", "mean_abs_error_m"] == pytest.approx(0.1 / 4, abs=1e-15)
    # streak over every measured frame, detected or not; the acquisition revolution never counts
    assert table.loc["fixed", "mean_streak_px"] == pytest.approx(12.0)
    assert table.loc["fixed", "max_streak_px"] == 14.0
    assert table.loc["active", "mean_streak_px"] == pytest.approx(1.5)
    assert table.loc["active", "jitter_deg"] == pytest.approx(0.5)
    assert table.loc["active", "mean_true_offset_px"] == pytest.approx(10.0)
    assert (table["frames"] == 6).all()


def test_runs_are_grouped_by_target_motion_shutter_and_seed():
    ones = np.ones(6, bool)
    runs = [fake_run(m, ones if s == "global" else np.r_[np.zeros(3, bool), np.ones(3, bool)],
                     np.full(6, 0.01), np.full(6, 1.0), seed=seed, shutter=s)
            for m in md.MOUNTS for s in md.SHUTTERS for seed in (0, 1)]
    runs.append(fake_run("fixed", np.zeros(6, bool), np.full(6, 0.01), np.full(6, 1.0), seed=0, motion="flight"))
    table = md.replicate_table(runs)
    assert len(table) == 13
    rolling = table[(table.shutter == "rolling") & (table.motion == "hover")]
    assert (rolling["common_rate"] == 0.5).all() and (table[(table.shutter == "global") & (table.motion == "hover")]["common_rate"] == 1.0).all()
    lone = table[table.motion == "flight"].iloc[0]
    assert lone["common_rate"] == 0.0 and math.isnan(lone["common_abs_error_m"])
    assert list(table["mount"].iloc[:4]) == ["fixed"] * 4  # fixed, stabilised, active order


# ----------------------------------------------------------------------------------------------
# hypotheses on hand-built replicate tables
# ----------------------------------------------------------------------------------------------
def designed_errors():
    """Per cell: (common error m, streak px) shaped so that every hypothesis holds widely."""
    cells = {}
    for target, motion, mount, shutter in itertools.product(md.TARGETS, md.MOTIONS, md.MOUNTS, md.SHUTTERS):
        error = {"fixed": 0.100, "stabilised": 0.060, "active": 0.010}[mount]
        if motion == "flight" and mount == "stabilised":
            error = 0.080
        if shutter == "rolling":
            error += 0.030 if mount == "fixed" else 0.002
        streak = {"fixed": 40.0, "stabilised": 10.0, "active": 2.0}[mount]
        cells[(target, motion, mount, shutter)] = (error, streak)
    return cells


def make_replicates(cells, overrides=None):
    rows = []
    for (target, motion, mount, shutter), (error, streak) in cells.items():
        for seed in SEEDS:
            rows.append(dict(target=target, motion=motion, mount=mount, shutter=shutter, seed=seed,
                             common_abs_error_m=error + JITTER[seed], mean_streak_px=streak + 10 * JITTER[seed]))
    df = pd.DataFrame(rows)
    for (target, motion, mount, shutter, column), value in (overrides or {}).items():
        sel = (df.target == target) & (df.motion == motion) & (df["mount"] == mount) & (df.shutter == shutter)
        df.loc[sel, column] = value
    return df


def test_every_hypothesis_holds_on_designed_replicates():
    v = md.check_hypotheses(make_replicates(designed_errors()))
    assert list(dict.fromkeys(v["id"])) == ["H1", "H2", "H3", "H4"]
    assert [int((v["id"] == h).sum()) for h in ("H1", "H2", "H3", "H4")] == [24, 4, 24, 12]
    assert (v["verdict"] == stats.HOLDS).all(), v[v["verdict"] != stats.HOLDS]
    assert set(v.loc[v["id"] == "H3", "unit"]) == {"px"} and set(v.loc[v["id"] != "H3", "unit"]) == {"m"}
    h4 = v[(v["id"] == "H4") & (v["condition"] == "sphere, hover") & (v["a"] == "cost active")].iloc[0]
    assert h4["mean_a"] == pytest.approx(0.002, abs=1e-12) and h4["mean_b"] == pytest.approx(0.030, abs=1e-12)
    h3 = v[(v["id"] == "H3") & (v["a"] == "active")].iloc[0]
    assert h3["delta"] == pytest.approx(1.0)  # the pixel floor, not 10 % of 2 px


def test_each_hypothesis_fails_where_its_numbers_say_so():
    cells = designed_errors()
    # H1 opposite: the stabilised camera worse than fixed in sphere hover, global
    cells[("sphere", "hover", "stabilised", "global")] = (0.150, 10.0)
    # H2 no effect: active ≈ stabilised in ArUco flight (0.2 mm apart, δ = 8 mm), both shutters,
    # with the same rolling-shutter cost for both (H4 unchanged)
    cells[("aruco", "flight", "active", "global")] = (0.0800, 2.0)
    cells[("aruco", "flight", "active", "rolling")] = (0.0822, 2.0)
    cells[("aruco", "flight", "stabilised", "global")] = (0.0798, 10.0)
    cells[("aruco", "flight", "stabilised", "rolling")] = (0.0820, 10.0)
    # H3: stabilised streak only 0.5 px below fixed in sphere vibration, global (δ = 1 px)
    cells[("sphere", "vibration", "stabilised", "global")] = (0.060, 39.5)
    v = md.check_hypotheses(make_replicates(cells)).set_index(["id", "condition", "a"])
    assert v.loc[("H1", "sphere, hover, global", "stabilised"), "verdict"] == stats.DOES_NOT_HOLD
    assert v.loc[("H1", "sphere, hover, global", "stabilised"), "low"] > 0
    for shutter in md.SHUTTERS:
        assert v.loc[("H2", f"aruco, flight, {shutter}", "active"), "verdict"] == stats.DOES_NOT_HOLD
    assert v.loc[("H3", "sphere, vibration, global", "stabilised"), "verdict"] == stats.DOES_NOT_HOLD
    # H4 in sphere hover: fixed's cost is 0.030, stabilised's now 0.062 − 0.150 < 0: holds more strongly
    assert v.loc[("H4", "sphere, hover", "cost stabilised"), "verdict"] == stats.HOLDS
    assert (v["verdict"] != stats.HOLDS).sum() == 4


def test_replicates_without_common_frames_leave_their_pairs_out():
    cells = designed_errors()
    over = {("aruco", m, mount, s, "common_abs_error_m"): np.nan
            for m in md.MOTIONS for mount in md.MOUNTS for s in md.SHUTTERS}
    df = make_replicates(cells, over)
    # two replicates of one cell measured something: still fewer than two complete pairs for H1
    sel = (df.target == "aruco") & (df.motion == "hover") & (df["mount"] == "fixed") & (df.shutter == "global")
    df.loc[sel & (df.seed <= 1), "common_abs_error_m"] = 0.1
    v = md.check_hypotheses(df)
    aruco_errors = v[(v["id"] != "H3") & v["condition"].str.startswith("aruco")]
    assert len(aruco_errors) == 12 + 2 + 6
    assert (aruco_errors["verdict"] == stats.INCONCLUSIVE).all() and (aruco_errors["n"] == 0).all()
    assert aruco_errors["low"].isna().all()
    text = md.hypotheses_markdown(v)
    assert "only 0 replicate(s) have frames where every mount detected the target" in text
    # the streak needs no detection: H3 is judged for ArUco too
    assert (v[(v["id"] == "H3") & v["condition"].str.startswith("aruco")]["verdict"] == stats.HOLDS).all()


def test_a_noisy_difference_is_inconclusive():
    cells = designed_errors()
    df = make_replicates(cells)
    sel = (df.target == "sphere") & (df.motion == "flight") & (df["mount"] == "active") & (df.shutter == "global")
    df.loc[sel, "common_abs_error_m"] = 0.080 + np.array([-0.03, 0.03, -0.03, 0.03, -0.03, 0.02])
    v = md.check_hypotheses(df).set_index(["id", "condition", "a"])
    row = v.loc[("H2", "sphere, flight, global", "active")]
    assert row["verdict"] == stats.INCONCLUSIVE and row["low"] < 0 < row["high"]


def test_missing_cells_and_duplicate_seeds_are_clear_errors():
    df = make_replicates(designed_errors())
    with pytest.raises(ValueError, match="no rows for sphere/hover/active/global"):
        md.check_hypotheses(df[~((df.target == "sphere") & (df.motion == "hover") & (df["mount"] == "active")
                                 & (df.shutter == "global"))])
    with pytest.raises(ValueError, match="seed twice"):
        md.check_hypotheses(pd.concat([df, df.iloc[:1]]))
    with pytest.raises(ValueError, match="no runs"):
        md.check_hypotheses(df.assign(target="cube"))


def test_one_motion_checks_what_it_can():
    df = make_replicates(designed_errors())
    v = md.check_hypotheses(df[df.motion == "hover"])
    assert [int((v["id"] == h).sum()) for h in ("H1", "H2", "H3", "H4")] == [8, 0, 8, 4]


def test_a_partial_grid_checks_only_the_cells_it_ran():
    """Notebook 09's test size: the sphere on two motions, the marker in flight only."""
    df = make_replicates(designed_errors())
    ran = ((df.target == "sphere") & df.motion.isin(["vibration", "flight"])) | ((df.target == "aruco")
                                                                                 & (df.motion == "flight"))
    v = md.check_hypotheses(df[ran])
    # H1, H3: 2 per cell and shutter; H2: the flight cells; H4: 2 per cell
    assert [int((v["id"] == h).sum()) for h in ("H1", "H2", "H3", "H4")] == [12, 4, 12, 6]
    assert set(v["condition"].str.split(", ").str[:2].str.join(", ")) == {"sphere, vibration", "sphere, flight",
                                                                         "aruco, flight"}
    assert (v["verdict"] == stats.HOLDS).all()


def test_a_shutter_a_cell_did_not_run_is_left_out_and_h4_needs_both():
    """Notebook 09's test size: the rolling shutter only for the sphere in flight."""
    df = make_replicates(designed_errors())
    ran = ((df.target == "sphere") & df.motion.isin(["vibration", "flight"])) | ((df.target == "aruco")
                                                                                 & (df.motion == "flight"))
    ran &= (df.shutter == "global") | ((df.target == "sphere") & (df.motion == "flight"))
    v = md.check_hypotheses(df[ran])
    # H1, H3: 2 per cell and shutter run (sphere vibration 1, sphere flight 2, marker flight 1); H2: the flight
    # cells' shutters; H4: the one cell with both shutters
    assert [int((v["id"] == h).sum()) for h in ("H1", "H2", "H3", "H4")] == [8, 3, 8, 2]
    assert set(v.loc[v["id"] == "H4", "condition"]) == {"sphere, flight"}
    assert set(v.loc[v["condition"].str.endswith("rolling"), "condition"]) == {"sphere, flight, rolling"}
    assert (v["verdict"] == stats.HOLDS).all()
    # a shutter run by some mounts of a cell but not all is still a clear error
    with pytest.raises(ValueError, match="no rows for sphere/vibration/stabilised/rolling"):
        md.check_hypotheses(df[ran | ((df.target == "sphere") & (df.motion == "vibration") & (df["mount"] == "fixed"))])


def test_markdown_gives_counts_reasons_and_detection_rates():
    cells = designed_errors()
    cells[("sphere", "hover", "stabilised", "global")] = (0.150, 10.0)
    df = make_replicates(cells)
    v = md.check_hypotheses(df)
    summary = pd.DataFrame([dict(target=t, motion=m, mount=mount, shutter=s, detection_rate=0.25)
                            for t, m, mount, s in cells])
    text = md.hypotheses_markdown(v, summary)
    assert "| H1 | 23 | 1 | 0 |" in text
    assert "the opposite is measured: stabilised exceeds fixed by 50.00 mm" in text
    assert "| sphere | hover | global | 0.25 | 0.25 | 0.25 |" in text
    assert text.count("| **holds** |") == 2 * 63  # each at 95 % and in the family (Holm)


def test_report_writes_tables_verdicts_figures_and_metadata(tmp_path):
    """A short version of the study (one target and motion, 12 frames a run) through the report writer."""
    import json

    from gimbal_lab.runner import run
    from gimbal_lab.studies import report

    study = md.MovingDroneStudy(replicates=2, fps=10.0, period_s=0.6)
    configs = md.grid(study, targets=("sphere",), motions=("vibration",))
    configs += md.arm_grid(study, targets=("sphere",), motions=("vibration",))
    results = run(configs, jobs=1, progress=False)
    written = report.write(tmp_path, md.make_report(results, study))
    names = sorted(p.relative_to(tmp_path).as_posix() for p in written)
    for name in ("summary.csv", "replicates.parquet", "replicates.csv", "verdicts.csv", "claims.md", "study.json",
                 "pipelines.csv", "every_pipeline.csv", "gains.csv", "gain_summary.csv", "figures/gains.png",
                 "figures/mount_bars.png", "figures/example_frames_sphere.svg", "figures/hypotheses_forest.png"):
        assert name in names and (tmp_path / name).stat().st_size > 0
    meta = json.loads((tmp_path / "study.json").read_text())
    assert meta["study"] == "moving-drone" and meta["runs"] == 20 and meta["parameters"] == study.to_dict()
    verdicts = pd.read_csv(tmp_path / "verdicts.csv")
    # BP1, BP2, SP1, SP2 per shutter; D1, D2; H1, H3, H4 (no flight: no H2)
    assert verdicts["id"].value_counts().sort_index().to_dict() == {"BP1": 2, "BP2": 2, "D1": 1, "D2": 1, "H1": 4,
                                                                    "H3": 4, "H4": 2, "SP1": 2, "SP2": 2}
    every = pd.read_csv(tmp_path / "every_pipeline.csv")
    assert sorted(set(every["pipeline"])) == sorted(("active (paper)", "active (best)") + md.PASSIVE_PIPELINES["sphere"])
    assert len(every) == 2 * 2 * 6  # shutters × seeds × pipelines
    assert {"p_value", "p_holm", "verdict_holm"} <= set(verdicts.columns)
    replicates = pd.read_parquet(tmp_path / "replicates.parquet")
    assert len(replicates) == 20 and replicates["arm"].value_counts().to_dict() == {"full": 12, "sharp": 4, "static": 4}
    assert len(pd.read_csv(tmp_path / "summary.csv")) == 6  # the study's cells only
    assert set(pd.read_csv(tmp_path / "gains.csv")["gain"]) == {"G_full", "G_sharp", "G_static"}
    assert "# Moving drone: hypotheses H1–H4, measured" in (tmp_path / "claims.md").read_text()


# ----------------------------------------------------------------------------------------------
# the strongest passive baseline and the gain, decomposed
# ----------------------------------------------------------------------------------------------
def test_arm_grid_shares_the_study_draws_and_changes_only_exposure_or_target_path():
    study = md.MovingDroneStudy(replicates=3)
    arms = md.arm_grid(study)
    assert len(arms) == 2 * 2 * 3 * 2 * 3 and len(set(arms)) == len(arms)
    full = {(c.target.kind, c.platform.motion, c.pointing.mount, c.seed): c for c in md.grid(study)
            if c.camera.readout_s == 0}
    for c in arms:
        twin = full[(c.target.kind, c.platform.motion, c.pointing.mount, c.seed)]
        assert c.pointing.mount in ("stabilised", "active") and c.camera.readout_s == 0
        if md.arm_of(c) == "sharp":
            assert c.camera.exposure_s == 0 and c.replace(camera=twin.camera) == twin
        else:
            assert md.arm_of(c) == "static" and c.target.trajectory == "stationary"
            assert c.camera.exposure_s == study.exposure_s and c.replace(target=twin.target) == twin
    assert {md.arm_of(c) for c in md.grid(study)} == {"full"}
    with pytest.raises(ValueError, match="arm"):
        study.config("sphere", "hover", "active", "global", 0, arm="blurred")


def exact_run(mount, detected, errors, alt_detected, alt_errors, seed=0, arm="full", motion="hover"):
    """fake_run with the sphere's exact fit in alt_* (the acquisition revolution: 1 m everywhere)."""
    study = md.MovingDroneStudy(replicates=2, fps=3.0, period_s=2.0)
    r = fake_run(mount, np.asarray(detected, bool), np.asarray(errors, float), np.ones(6), seed=seed, motion=motion)
    config = study.config("sphere", motion, mount, "global", seed, arm=arm)
    f = r.frames.copy()
    f["alt_detected"] = np.r_[np.ones(6, bool), np.asarray(alt_detected, bool)]
    f["alt_abs_error_m"] = np.r_[np.ones(6), np.asarray(alt_errors, float)]
    return TrackingResult(config=config, frames=f)


def test_pipeline_and_gain_columns_on_hand_built_runs():
    e = np.array([0.01, 0.02, 0.03, 0.04, 0.05, 0.06])
    runs = [exact_run("fixed", [1] * 6, 10 * e, [1] * 6, 10 * e),
            exact_run("stabilised", [1] * 6, 2 * e, [1, 1, 1, 1, 0, 1], e),
            exact_run("active", [1, 1, 1, 0, 1, 1], 3 * e, [1, 1, 1, 1, 1, 0], 0.5 * e)]
    table = md.replicate_table(runs).set_index("mount")
    # gain frames: stabilised's and active's exact fits both detected: 0, 1, 2, 3
    assert table.loc["stabilised", "pair_abs_error_m"] == pytest.approx(0.025, rel=1e-12)
    assert table.loc["active", "pair_abs_error_m"] == pytest.approx(0.0125, rel=1e-12)
    # BP frames: those and the active mount's own detections: 0, 1, 2
    assert table.loc["active", "bp_rate"] == pytest.approx(0.5, rel=1e-12)
    assert table.loc["active", "bp_paper_abs_error_m"] == pytest.approx(0.06, rel=1e-12)
    assert table.loc["active", "bp_best_abs_error_m"] == pytest.approx(0.01, rel=1e-12)
    assert table.loc["stabilised", "bp_best_abs_error_m"] == pytest.approx(0.02, rel=1e-12)
    pipes = md.pipeline_table(table.reset_index()).set_index("pipeline")["abs_error_m"]
    assert pipes.to_dict() == pytest.approx({"active (paper)": 0.06, "active (best)": 0.01, "best passive": 0.02})
    # SP frames: every mount's own and exact estimators detected: 0, 1, 2 (the fixed mount detects all)
    assert table["sp_rate"].to_numpy() == pytest.approx([0.5, 0.5, 0.5], rel=1e-12)
    every = md.every_pipeline_table(table.reset_index()).set_index("pipeline")["abs_error_m"]
    assert every.to_dict() == pytest.approx({"active (paper)": 0.06, "active (best)": 0.01,
                                             "fixed (paper)": 0.2, "stabilised (paper)": 0.04,
                                             "fixed (best)": 0.2, "stabilised (best)": 0.02}, rel=1e-12)
    gains = md.gain_table(table.reset_index())
    assert len(gains) == 1 and gains.iloc[0]["G_m"] == pytest.approx(0.0125, rel=1e-12)
    # the acquisition revolution (1 m, all detected) never counts
    columns = ["pair_abs_error_m", "bp_paper_abs_error_m", "bp_best_abs_error_m", "sp_paper_abs_error_m",
               "sp_best_abs_error_m"]
    assert (table.loc[["stabilised", "active"], columns] < 0.1).all().all()


def designed_arm_replicates(g_full=0.030, g_sharp=0.010, g_static=0.005):
    """Replicates of every cell (designed_errors) plus the arms, with per-arm gains G on the
    exact estimator's pair errors (stabilised − active) and BP columns."""
    df = make_replicates(designed_errors())
    df["arm"] = "full"
    gains = {"full": g_full, "sharp": g_sharp, "static": g_static}
    df["pair_abs_error_m"] = np.where(df["mount"] == "stabilised", 0.002 + g_full, 0.002) + np.tile(JITTER, len(df) // 6)
    df["bp_paper_abs_error_m"] = np.where(df["mount"] == "active", 0.050, np.nan)
    df["bp_best_abs_error_m"] = np.where(df["mount"] == "active", 0.004, 0.020)
    df["bp_rate"] = 0.9
    # SP: every passive pipeline well above both active ones (sphere: fixed and stabilised, own and exact)
    df["sp_paper_abs_error_m"] = df["mount"].map({"fixed": 0.100, "stabilised": 0.060, "active": 0.050})
    df["sp_best_abs_error_m"] = df["mount"].map({"fixed": 0.090, "stabilised": 0.020, "active": 0.004})
    df[["sp_paper_abs_error_m", "sp_best_abs_error_m"]] += np.tile(JITTER, len(df) // 6)[:, None]
    df["sp_rate"] = 0.8
    rows = []
    for arm in ("sharp", "static"):
        for target, motion, mount in itertools.product(md.TARGETS, md.MOTIONS, ("stabilised", "active")):
            for seed in SEEDS:
                rows.append(dict(arm=arm, target=target, motion=motion, mount=mount, shutter="global", seed=seed,
                                 pair_abs_error_m=(0.002 + gains[arm] if mount == "stabilised" else 0.002)
                                 + 0.5 * JITTER[seed]))
    return pd.concat([df, pd.DataFrame(rows)], ignore_index=True)


def test_bp_and_decomposition_claims_on_designed_replicates():
    v = md.check_hypotheses(designed_arm_replicates())
    counts = v["id"].value_counts().to_dict()
    assert counts == {"H1": 24, "H2": 4, "H3": 24, "H4": 12, "BP1": 12, "BP2": 12, "D1": 6, "D2": 6, "SP1": 12,
                      "SP2": 12}
    by = {cid: v[v["id"] == cid] for cid in ("BP1", "BP2", "D1", "D2")}
    # the paper's loop (50 mm) loses to the best passive pipeline (20 mm); the best active (4 mm) wins
    assert (by["BP1"]["verdict"] == stats.DOES_NOT_HOLD).all() and (by["BP2"]["verdict"] == stats.HOLDS).all()
    assert by["BP2"]["difference"].to_numpy() == pytest.approx(-0.016)
    # G_sharp 10 mm and G_static 5 mm below G_full 30 mm
    assert (by["D1"]["verdict"] == stats.HOLDS).all() and (by["D2"]["verdict"] == stats.HOLDS).all()
    assert by["D1"]["difference"].to_numpy() == pytest.approx(-0.020, abs=1e-9)
    assert (v["verdict_holm"] == v["verdict"]).all()  # wide effects stay decisive in a family of 124
    # when the sharp arm's gain exceeds the full one, D1 does not hold; D2 is untouched
    v = md.check_hypotheses(designed_arm_replicates(g_sharp=0.050))
    assert (v[v["id"] == "D1"]["verdict"] == stats.DOES_NOT_HOLD).all()
    assert (v[v["id"] == "D2"]["verdict"] == stats.HOLDS).all()
    shares = md.gain_summary(md.gain_table(designed_arm_replicates()))
    got = shares[(shares.target == "sphere") & (shares.motion == "hover")].set_index("gain")["mean_m"]
    assert got.to_dict() == pytest.approx({"G_full": 0.030, "G_sharp": 0.010, "G_static": 0.005,
                                           "G_full − G_sharp": 0.020}, abs=1e-9)


def test_verdict_lines_render_p_and_holm_when_present():
    v = md.check_hypotheses(designed_arm_replicates())
    lines = _params.verdict_lines(v, md.verdict_reason)
    head = lines[0]
    assert "| p |" in head and head.endswith("| verdict | p (Holm) | verdict (Holm) |")
    assert any(line.startswith("Of 124 conditions, at 95 % each:") and "At the family level (Holm" in line
               for line in lines)
    plain = _params.verdict_lines(v.drop(columns=["p_holm", "verdict_holm"]), md.verdict_reason)
    assert plain[0].endswith("| p | verdict |") and "family level" not in "\n".join(plain)


# ----------------------------------------------------------------------------------------------
# SP1, SP2: active against every passive pipeline (an intersection-union test)
# ----------------------------------------------------------------------------------------------
def test_sp_holds_only_against_every_passive_pipeline_and_names_the_one_that_decides():
    df = designed_arm_replicates()
    v = md.check_hypotheses(df)
    sp = {cid: v[v["id"] == cid] for cid in ("SP1", "SP2")}
    sphere = sp["SP1"]["condition"].str.startswith("sphere")
    # sphere: the paper's loop (50 mm) beats the fixed camera (90-100 mm) but not the stabilised
    # camera's exact fit (20 mm): SP1 does not hold, decided by that pipeline; BP1 says the same
    assert (sp["SP1"].loc[sphere, "verdict"] == stats.DOES_NOT_HOLD).all()
    assert set(sp["SP1"].loc[sphere, "b"]) == {"stabilised (best)"}
    # the marker has two passive pipelines (its exact estimator is its own PnP), 100 and 60 mm: SP1
    # holds against both
    assert (sp["SP1"].loc[~sphere, "verdict"] == stats.HOLDS).all()
    assert set(sp["SP1"].loc[~sphere, "b"]) <= set(md.PASSIVE_PIPELINES["aruco"])
    assert set(sp["SP1"]["passive_pipelines"]) == {2, 4}
    # the best active camera (4 mm) beats all four: SP2 holds, with the largest p of the four
    assert (sp["SP2"]["verdict"] == stats.HOLDS).all()
    # where the weak "best passive" of BP hides a strong pipeline, SP does not: make the stabilised
    # camera's exact fit bad (300 mm, as blur does) and its circle method as good as active (paper)
    bad = df.copy()
    stab = (bad["mount"] == "stabilised") & (bad["arm"] == "full")
    bad.loc[stab, "sp_best_abs_error_m"] = 0.300
    bad.loc[stab, "bp_best_abs_error_m"] = 0.300
    bad.loc[stab, "sp_paper_abs_error_m"] = bad.loc[(bad["mount"] == "active") & (bad["arm"] == "full"),
                                                   "sp_paper_abs_error_m"].to_numpy()
    v = md.check_hypotheses(bad)
    bp1, sp1 = v[v["id"] == "BP1"], v[v["id"] == "SP1"]
    bp1, sp1 = bp1[bp1["condition"].str.startswith("sphere")], sp1[sp1["condition"].str.startswith("sphere")]
    assert (bp1["verdict"] == stats.HOLDS).all()  # against the weak baseline
    assert (sp1["verdict"] == stats.DOES_NOT_HOLD).all() and set(sp1["b"]) == {"stabilised (paper)"}
    assert sp1["difference"].to_numpy() == pytest.approx(0.0, abs=1e-12)
    assert all("decided against stabilised (paper)" in md.verdict_reason(r) for r in sp1.itertuples())


#: Paired differences active (paper) − P per seed for an inconclusive SP1 on the sphere, each with
#: the 95 % interval by hand, mean ± t·s/√6 (t₀.₉₇₅(5) = 2.5706 from a printed table, s = 1.0954 ×
#: the spread for the ±1 pattern): the one reaching highest is neither the first, the widest, nor
#: the one with the largest or the smallest p or the highest mean.
_UPDOWN = np.array([-1.0, 1.0, -1.0, 1.0, -1.0, 1.0])
SP_OPEN = {
    "fixed (paper)": 0.014 * _UPDOWN,  # [−16.1, 16.1] mm, the largest p (0.46: twice the TOST p against ±5 mm)
    "stabilised (paper)": -0.015 + 0.030 * _UPDOWN,  # [−49.5, 19.5] mm: reaches highest (p 0.31)
    "fixed (best)": -0.030 + 0.040 * _UPDOWN,  # [−76.0, 16.0] mm: the widest, the lowest (p 0.15)
    "stabilised (best)": 0.004 + 0.003 * _UPDOWN,  # [0.6, 7.4] mm: does not hold at 95 % (p 0.031), not at 0.05 / 4
}
T975_DF5 = 2.5706


def test_an_inconclusive_sp_row_names_the_passive_pipeline_whose_interval_reaches_highest():
    """docs/design.md, the moving drone's SP1 and SP2: for "inconclusive" the row shows the numbers
    of the comparison whose interval reaches highest and names that passive pipeline."""
    df = designed_arm_replicates()
    full_sphere = (df["arm"] == "full") & (df["target"] == "sphere")
    seed = df["seed"].to_numpy()
    active_paper = 0.050 + JITTER[seed]  # the designed active (paper) error of each row's seed
    for pipeline, d in SP_OPEN.items():
        mount, estimator = pipeline.split(" ")
        column = "sp_paper_abs_error_m" if estimator == "(paper)" else "sp_best_abs_error_m"
        rows = full_sphere & (df["mount"] == mount)
        df.loc[rows, column] = (active_paper - d[seed])[rows.to_numpy()]
    v = md.check_hypotheses(df)
    sp1 = v[(v["id"] == "SP1") & v["condition"].str.startswith("sphere")]
    assert len(sp1) == 6 and (sp1["verdict"] == stats.INCONCLUSIVE).all(), sp1[["condition", "verdict", "b"]]
    assert set(sp1["b"]) == {"stabilised (paper)"}
    d = SP_OPEN["stabilised (paper)"]
    half = T975_DF5 * d.std(ddof=1) / math.sqrt(6)
    assert sp1["difference"].to_numpy() == pytest.approx(np.full(6, d.mean()), abs=1e-12)
    assert sp1["high"].to_numpy() == pytest.approx(np.full(6, d.mean() + half), abs=1e-6)
    # its own p (inconclusive, no Bonferroni factor): the paired t-test of a zero difference,
    # smaller than twice the TOST p here (the interval is far from inside ±δ)
    from scipy.stats import t as student_t

    p_zero = 2 * student_t.sf(abs(d.mean()) / (d.std(ddof=1) / math.sqrt(6)), 5)
    assert sp1["p_value"].to_numpy() == pytest.approx(np.full(6, p_zero), rel=1e-6)
    assert all("stabilised (paper)" in md.verdict_reason(r) for r in sp1.itertuples())
    # the same choice from stats.against_every directly, in another order of the comparisons
    a = 0.050 + JITTER
    order = ["stabilised (best)", "fixed (best)", "stabilised (paper)", "fixed (paper)"]
    j, verdict = stats.against_every([stats.less_than(a, a - SP_OPEN[name]) for name in order])
    assert (order[j], verdict.verdict) == ("stabilised (paper)", stats.INCONCLUSIVE)


def test_against_every_is_an_intersection_union_test_with_a_bonferroni_failure():
    a = np.array([1.0, 1.1, 0.9, 1.05])
    far, near = stats.less_than(a, a + 1.0 + [0, 0.1, -0.1, 0.05]), stats.less_than(a, a + 0.5 + [0, 0.1, -0.1, 0])
    # every comparison holds: holds, the largest p, that comparison's numbers
    j, v = stats.against_every([far, near])
    assert v.verdict == stats.HOLDS and j == int(np.argmax([far.p_value, near.p_value]))
    assert v.p_value == max(far.p_value, near.p_value)
    # one comparison inconclusive: the whole claim is, whichever holds
    noisy = stats.less_than(a, a + [0.5, -0.5, 0.6, -0.4])
    assert noisy.verdict == stats.INCONCLUSIVE
    j, v = stats.against_every([far, noisy, near])
    assert (j, v.verdict) == (1, stats.INCONCLUSIVE)
    # one comparison does not hold (A exceeds B): does not hold, p scaled by k
    worse = stats.less_than(a + 0.5 + [0, 0.01, -0.01, 0], a)
    j, v = stats.against_every([far, worse, near])
    assert (j, v.verdict) == (1, stats.DOES_NOT_HOLD) and v.p_value == pytest.approx(3 * worse.p_value, rel=1e-12)
    assert v.difference == worse.difference and v.low == worse.low  # the deciding comparison's numbers
    # a "does not hold" decisive at 95 % but not at 0.05 / k stays inconclusive
    b = a + [0.3, 0.1, 0.25, 0.15]  # p = 0.022: decisive at 95 %, not at 0.05 / 4
    edge = stats.less_than(b, a)
    assert edge.verdict == stats.DOES_NOT_HOLD and 0.05 / 4 < edge.p_value < 0.05, edge
    j, v = stats.against_every([far, far, far, edge])
    assert (j, v.verdict) == (3, stats.INCONCLUSIVE) and v.p_value == pytest.approx(4 * edge.p_value, rel=1e-12)
    assert stats.against_every([edge])[1].verdict == stats.DOES_NOT_HOLD  # alone it decides
    with pytest.raises(ValueError, match="one or more"):
        stats.against_every([])
