"""The lens sweep: its grid (lenses, sizes, cone, draws), its replicate table on hand-built frame
tables, and its hypotheses on hand-built replicate tables, one case per outcome."""

import itertools
import math

import numpy as np
import pandas as pd
import pytest

from gimbal_lab import stats
from gimbal_lab.camera import BrownConrady, KannalaBrandt, project
from gimbal_lab.config import Camera
from gimbal_lab.simulation import CONE_RANGE_M, TrackingConfig, TrackingResult
from gimbal_lab.studies import load
from gimbal_lab.studies import lens_sweep as ls
from gimbal_lab.studies.paper import replicate_phase_s

SEEDS = range(6)
JITTER = np.array([-1, 1, -1, 1, -1, 1]) * 1e-4  # ±0.1 mm (or ±1e-4 % / ms): designed effects dwarf it


# ----------------------------------------------------------------------------------------------
# grid and parameters
# ----------------------------------------------------------------------------------------------
def test_grid_is_76_cells_times_replicates_with_shared_draws():
    study = ls.LensSweepStudy(replicates=2, first_seed=3)
    configs = ls.grid(study)
    assert len(configs) == 76 * 2
    cells = {(c.target.kind, ls.lens_name(c), c.estimator.lens_strategy, c.pointing.mode) for c in configs}
    expected = {(t, lens.name, s, m) for t in ls.TARGETS for lens in ls.LENSES for s in ls.strategies_for(lens.name)
                for m in ls.MODES}
    assert cells == expected and len(expected) == 76
    assert ls.strategies_for("pinhole") == ("ignore",)
    for c in configs:
        assert c.target.trajectory == "cone" and c.platform.altitude_m == ls.ALTITUDE_M
        assert c.target.start_phase_s == replicate_phase_s(c.seed, 2.0)
        assert c.pointing.kind == ("paper" if c.pointing.active else "stabilised")
    assert sorted({c.seed for c in configs}) == [3, 4]
    # the lenses: the default Brown–Conrady scaled, and equidistant fisheyes
    by_lens = {ls.lens_name(c): c for c in configs}
    lens_of = {name: c.camera.lens_model for name, c in by_lens.items()}
    assert lens_of["pinhole"] is None
    assert lens_of["BC ×1.5"].k1 == pytest.approx(1.5 * BrownConrady.default().k1, rel=1e-15)
    assert lens_of["BC ×0.5"].p2 == pytest.approx(0.5 * BrownConrady.default().p2, rel=1e-15)
    assert lens_of["fisheye 185°"] == KannalaBrandt()
    assert math.degrees(by_lens["fisheye 150°"].camera.hfov_rad) == pytest.approx(150.0)


@pytest.mark.parametrize("lens", [x.name for x in ls.LENSES])
def test_targets_image_as_in_the_paper_study_on_the_axis_and_the_cone_sits_at_0_7_of_the_half_field(lens):
    c = ls.LensSweepStudy(replicates=2).config("sphere", lens, "ignore", "passive", 0)
    # on the axis at 3 m a point r off it is imaged where the paper camera images it, to 0.5 %: the size
    # follows the focal length, and the equidistant fisheye's atan(r/3) falls short of r/3 by 0.3 % at 185°
    edge = np.array([[c.target.sphere_radius_m, 0.0, CONE_RANGE_M]])
    radius_px = project(edge, c.camera.intrinsics, c.camera.lens_model)[0, 0] - c.camera.intrinsics.cx
    paper_px = 554.2562584220408 * 0.10 / CONE_RANGE_M
    assert radius_px == pytest.approx(paper_px, rel=5e-3)
    assert c.target.marker_length_m / c.target.sphere_radius_m == pytest.approx(3.0)
    # every point of the path is 3 m from the home camera, 0.7 × half field off the home axis
    p = c.path.position(np.linspace(0.0, 2.0, 13)) - c.home_camera_m
    assert np.linalg.norm(p, axis=1) == pytest.approx(np.full(13, CONE_RANGE_M), abs=1e-12)
    off_axis = np.degrees(np.arccos(p[:, 0] / CONE_RANGE_M))
    assert off_axis == pytest.approx(np.full(13, 0.35 * math.degrees(c.camera.hfov_rad)), abs=1e-9)
    # the widest target stays above the ground
    lowest = c.path.position(np.linspace(0.0, 2.0, 721))[:, 2].min() - 2 / 3 * c.target.marker_length_m
    assert lowest > 0.5


@pytest.mark.parametrize("args, name", [
    (("cube", "BC ×1", "ignore", "passive", 0), "target"), (("sphere", "BC ×2", "ignore", "passive", 0), "lens"),
    (("sphere", "pinhole", "rectify", "passive", 0), "strategy"),
    (("sphere", "BC ×1", "ignore", "fixed", 0), "mode"),
])
def test_bad_cell_names_are_clear_errors(args, name):
    with pytest.raises(ValueError, match=name):
        ls.LensSweepStudy(replicates=2).config(*args)


def test_config_from_toml_and_the_shipped_file_is_the_default(tmp_path):
    path = tmp_path / "ls.toml"
    path.write_text('[lens-sweep]\nreplicates = 4\n')
    assert ls.LensSweepStudy.from_toml(path).seeds == [0, 1, 2, 3]
    path.write_text('[lens-sweep]\nlenses = ["BC ×1"]\n')
    with pytest.raises(ValueError, match="unknown key.*lenses"):
        ls.LensSweepStudy.from_toml(path)
    from pathlib import Path

    shipped = Path(__file__).parent.parent / "data" / "studies" / "lens-sweep.toml"
    assert ls.LensSweepStudy.from_toml(shipped) == ls.LensSweepStudy()
    assert load("lens-sweep") is ls and ls.Study is ls.LensSweepStudy


def test_lens_name_rejects_a_lens_outside_the_sweep():
    with pytest.raises(ValueError, match="not one of the sweep"):
        ls.lens_name(TrackingConfig(camera=Camera(lens=BrownConrady(k1=-0.1))))


# ----------------------------------------------------------------------------------------------
# replicate table on hand-built runs
# ----------------------------------------------------------------------------------------------
def fake_run(strategy, detected, errors, seed=0, lens="BC ×1", mode="passive", detect_s=0.3):
    """6 frames per revolution × 2 revolutions; the acquisition revolution (all detected, 1 m error)
    must not count."""
    study = ls.LensSweepStudy(replicates=2, fps=3.0, period_s=2.0)
    config = study.config("sphere", lens, strategy, mode, seed)
    n = int(config.frames_per_revolution)
    frames = pd.DataFrame({
        "frame": np.arange(2 * n),
        "detected": np.r_[np.ones(n, bool), detected],
        "abs_error_m": np.r_[np.ones(n), np.where(detected, errors, np.nan)],
        "true_offset_px": np.r_[np.zeros(n), np.full(n, 10.0)],
        "alt_detected": np.r_[np.ones(n, bool), detected],
        "alt_abs_error_m": np.r_[np.ones(n), np.where(detected, 0.5 * np.asarray(errors), np.nan)],
    })
    return TrackingResult(config=config, frames=frames, timing={"detect_s": detect_s, "render_s": 1.2})


def test_common_frames_are_those_every_strategy_detected_and_costs_are_per_frame():
    d = {"ignore": [1, 1, 0, 1, 0, 1], "undistort": [1, 1, 1, 1, 0, 0], "rectify": [1, 1, 1, 1, 1, 1]}
    e = {"ignore": [0.1, 0.2, 0.3, 0.4, 0.5, 0.6], "undistort": [0.01, 0.02, 0.03, 0.04, 0.05, 0.06],
         "rectify": [0.001, 0.002, 0.003, 0.004, 0.005, 0.006]}
    runs = [fake_run(s, np.array(d[s], bool), np.array(e[s]), detect_s=0.012 * (i + 1)) for i, s in enumerate(d)]
    t = ls.replicate_table(runs).set_index("strategy")
    assert t.loc["ignore", "common_rate_pct"] == pytest.approx(50.0)  # frames 0, 1, 3 by hand
    assert t.loc["ignore", "common_abs_error_m"] == pytest.approx(0.7 / 3, abs=1e-15)
    assert t.loc["undistort", "common_abs_error_m"] == pytest.approx(0.07 / 3, abs=1e-15)
    assert t.loc["ignore", "detection_rate_pct"] == pytest.approx(400 / 6)
    assert t.loc["undistort", "mean_abs_error_m"] == pytest.approx(0.1 / 4, abs=1e-15)
    assert t.loc["undistort", "alt_abs_error_m"] == pytest.approx(0.05 / 4, abs=1e-15)
    assert t.loc["rectify", "estimate_ms"] == pytest.approx(1000 * 0.036 / 12)  # per frame of the whole run
    assert t.loc["ignore", "render_ms"] == pytest.approx(100.0)
    assert (t["lens"] == "BC ×1").all() and (t["family"] == "brown-conrady").all() and (t["frames"] == 6).all()


# ----------------------------------------------------------------------------------------------
# hypotheses on hand-built replicate tables
# ----------------------------------------------------------------------------------------------
def designed_cells():
    """Per cell: (own error m, common error m, detection %, cost ms), shaped so every hypothesis holds."""
    cells = {}
    strength = {lens.name: i for i, lens in enumerate(ls.LENSES)}
    for target, lens, mode in itertools.product(ls.TARGETS, (x.name for x in ls.LENSES), ls.MODES):
        for strategy in ls.strategies_for(lens):
            k = strength[lens] if lens.startswith(("BC", "pinhole")) else strength[lens] - 3
            error = 0.010 + (0.020 * k if mode == "passive" else 0.001 * k)
            if strategy == "rectify":
                error, rate = error + 0.050, 40.0
            else:
                rate = 95.0
            cost = {"ignore": 1.0, "undistort": 1.2, "rectify": 3.0}[strategy]
            cells[(target, lens, strategy, mode)] = (error, error, rate, cost)
    return cells


def make_replicates(cells, overrides=None):
    rows = []
    for (target, lens, strategy, mode), (own, common, rate, cost) in cells.items():
        for seed in SEEDS:
            rows.append(dict(target=target, lens=lens, strategy=strategy, mode=mode, seed=seed,
                             mean_abs_error_m=own + JITTER[seed], common_abs_error_m=common + JITTER[seed],
                             detection_rate_pct=rate + JITTER[seed], estimate_ms=cost + JITTER[seed]))
    df = pd.DataFrame(rows)
    for (target, lens, strategy, mode, column), value in (overrides or {}).items():
        sel = (df.target == target) & (df.lens == lens) & (df.strategy == strategy) & (df["mode"] == mode)
        df.loc[sel, column] = value
    return df


def test_every_hypothesis_holds_on_designed_replicates():
    v = ls.check_hypotheses(make_replicates(designed_cells()))
    assert list(dict.fromkeys(v["id"])) == ["H1", "H2", "H3"]
    # H1: 2 targets × 4 lenses × 2 modes × (error, rate); H2: 2 × 2 families; H3: 2 × 6 × 2 × (error, cost)
    assert [int((v["id"] == h).sum()) for h in ("H1", "H2", "H3")] == [32, 4, 48]
    assert (v["verdict"] == stats.HOLDS).all(), v[v["verdict"] != stats.HOLDS]
    assert set(v["unit"]) == {"m", "%", "ms"}


def test_each_outcome_is_reported_where_it_was_built():
    over = {
        # rectify as accurate as ignore on the 185° fisheye (no effect), and more accurate on 150°
        ("sphere", "fisheye 185°", "rectify", "active", "common_abs_error_m"): 0.010 + 0.003 + 1e-5,
        ("sphere", "fisheye 185°", "ignore", "active", "common_abs_error_m"): 0.010 + 0.003,
        ("sphere", "fisheye 150°", "rectify", "passive", "common_abs_error_m"): 0.001,
        # H3's cost reversed for the ArUco on BC ×1
        ("aruco", "BC ×1", "undistort", "active", "estimate_ms"): 5.0,
        # an H2 advantage that shrinks with distortion
        ("aruco", "fisheye 185°", "ignore", "passive", "mean_abs_error_m"): 0.010,
    }
    v = ls.check_hypotheses(make_replicates(designed_cells(), over)).set_index(["id", "condition", "unit"])
    assert v.loc[("H1", "sphere, fisheye 185°, active", "m"), "verdict"] == stats.DOES_NOT_HOLD
    assert v.loc[("H1", "sphere, fisheye 150°, passive", "m"), "verdict"] == stats.DOES_NOT_HOLD
    assert v.loc[("H1", "sphere, fisheye 150°, passive", "m"), "low"] > 0
    assert v.loc[("H3", "aruco, BC ×1, active", "ms"), "verdict"] == stats.DOES_NOT_HOLD
    assert v.loc[("H2", "aruco, fisheye", "m"), "verdict"] == stats.DOES_NOT_HOLD
    assert v.loc[("H2", "sphere, fisheye", "m"), "verdict"] == stats.HOLDS
    text = ls.hypotheses_markdown(v.reset_index())
    assert "no effect worth the name" in text and "the opposite is measured" in text


def test_a_strategy_without_common_detections_is_inconclusive_with_its_reason():
    over = {("aruco", "fisheye 120°", "rectify", "passive", "common_abs_error_m"): np.nan,
            ("aruco", "fisheye 120°", "ignore", "passive", "common_abs_error_m"): np.nan}
    v = ls.check_hypotheses(make_replicates(designed_cells(), over))
    row = v[(v["id"] == "H1") & (v["condition"] == "aruco, fisheye 120°, passive") & (v["unit"] == "m")].iloc[0]
    assert row["verdict"] == stats.INCONCLUSIVE and row["n"] == 0
    assert "nothing to compare" in ls.verdict_reason(row)


def test_a_partial_table_checks_what_it_holds():
    df = make_replicates(designed_cells())
    v = ls.check_hypotheses(df[df["lens"].isin(["BC ×1", "BC ×1.5"]) & (df["target"] == "sphere")])
    assert set(v["id"]) == {"H1", "H3"} and (v["verdict"] == stats.HOLDS).all()
    with pytest.raises(ValueError, match="no runs"):
        ls.check_hypotheses(df[df["lens"] == "nonesuch"])


@pytest.mark.parametrize("lens", ["BC ×1", "fisheye 120°", "fisheye 185°"])
def test_the_cones_pointing_demand_matches_a_numerical_derivative_of_the_direction(lens):
    c = ls.LensSweepStudy(replicates=2).config("sphere", lens, "ignore", "active", 0)
    demand = ls.cone_pointing_demand(c)
    t = np.linspace(0.0, c.target.period_s, 20001)
    d = c.path.position(t) - c.home_camera_m
    yaw = np.unwrap(np.arctan2(d[:, 1], d[:, 0]))
    pitch = np.arctan2(d[:, 2], np.hypot(d[:, 0], d[:, 1]))
    dt = t[1] - t[0]
    # central differences on a 1e-4 s grid: the peaks to 1e-6 relative
    assert np.abs(np.gradient(yaw, dt)).max() == pytest.approx(demand["peak_yaw_rate_rad_s"], rel=1e-6)
    assert np.abs(np.gradient(pitch, dt)).max() == pytest.approx(demand["peak_pitch_rate_rad_s"], rel=1e-6)
    assert np.degrees(pitch.max()) == pytest.approx(demand["peak_elevation_deg"], abs=1e-6)
    with pytest.raises(ValueError, match="cone"):
        ls.cone_pointing_demand(TrackingConfig())
