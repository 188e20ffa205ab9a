"""The occlusion study: occluder placement against brute-force geometry, episodes and run metrics
on hand-built frame tables, and the hypotheses on hand-built replicate tables, one case per outcome."""

import itertools
import math

import numpy as np
import pandas as pd
import pytest

from gimbal_lab import stats
from gimbal_lab.simulation import TrackingConfig, TrackingResult
from gimbal_lab.studies import load
from gimbal_lab.studies import occlusion as oc
from gimbal_lab.studies.paper import replicate_phase_s

SEEDS = range(6)
JITTER = np.array([-1, 1, -1, 1, -1, 1]) * 1e-3  # ±0.001°: designed effects dwarf it


# ----------------------------------------------------------------------------------------------
# occluders and grid
# ----------------------------------------------------------------------------------------------
@pytest.mark.parametrize("occlusion, wanted_s", [("pole 0.2 s", 0.2), ("panel 0.5 s", 0.5)])
def test_occluders_hide_the_circle_for_their_stated_time(occlusion, wanted_s):
    (occluder,) = oc.occluders_for(occlusion)
    config = TrackingConfig()
    # brute force, independent of hidden_time_s: 1 ms steps, the sight line sampled every 0.2 mm
    t = np.arange(0.0, config.target.period_s, 1e-3)
    camera = config.home_camera_m
    lo, hi = occluder.bounds_m
    s = np.linspace(0.0, 1.0, 20001)[:, None]
    hidden = [np.any(np.all((camera + s * (p - camera) >= lo) & (camera + s * (p - camera) <= hi), axis=1))
              for p in config.path.position(t)]
    assert np.mean(hidden) * config.target.period_s == pytest.approx(wanted_s, abs=0.003)
    assert occluder.centre_m[1] == 0.0 and occluder.bounds_m[1][2] == pytest.approx(camera[2])  # top at the camera


def test_the_longest_occlusion_hides_the_arc_below_the_camera():
    (panel,) = oc.occluders_for("panel 1.0 s")
    config = TrackingConfig()
    hidden_s = oc.hidden_time_s(panel)
    # the circle (radius 1 m about z = 2 m) is below the camera's height z_c for a fraction
    # 1/2 − asin((2 − z_c)/1)/π of the period
    below_s = config.target.period_s * (0.5 - math.asin(2.0 - config.home_camera_m[2]) / math.pi)
    assert below_s - 0.01 < hidden_s <= below_s
    assert oc.hidden_time_s(oc._occluder("panel", 0.75, config.home_camera_m)) == pytest.approx(hidden_s, abs=0.006)


def test_grid_is_32_cells_times_replicates_with_shared_draws():
    study = oc.OcclusionStudy(replicates=3)
    configs = oc.grid(study)
    assert len(configs) == 32 * 3
    assert len({c.key for c in configs}) == len(configs)
    for c in configs:
        assert c.pointing.active and c.target.kind == "sphere" and c.revolutions == 3.0
        assert c.target.start_phase_s == replicate_phase_s(c.seed, 2.0)
    cells = {oc._names(c) for c in configs}
    assert cells == set(itertools.product(oc.OCCLUSIONS, oc.TARGETS, oc.LOOPS))
    assert load("occlusion").Study is oc.OcclusionStudy


@pytest.mark.parametrize("args, name", [(("fog", "circle", "CV", 0), "occlusion"), (("none", "line", "CV", 0), "target"),
                                        (("none", "circle", "EKF", 0), "loop")])
def test_bad_cell_names_are_clear_errors(args, name):
    with pytest.raises(ValueError, match=name):
        oc.OcclusionStudy(replicates=2).config(*args)


def test_config_from_toml_and_the_shipped_file_is_the_default(tmp_path):
    from pathlib import Path

    shipped = Path(__file__).resolve().parents[1] / "data" / "studies" / "occlusion.toml"
    assert oc.OcclusionStudy.from_toml(shipped) == oc.OcclusionStudy()
    bad = tmp_path / "bad.toml"
    bad.write_text("[occlusion]\nreplicates = 3\nfilter = 'ekf'\n")
    with pytest.raises(ValueError, match="filter"):
        oc.OcclusionStudy.from_toml(bad)
    other = Path(__file__).resolve().parents[1] / "data" / "studies" / "lens-sweep.toml"
    with pytest.raises(ValueError, match=r"no \[occlusion\] table \(it holds \[lens-sweep\]\)"):
        oc.OcclusionStudy.from_toml(other)


# ----------------------------------------------------------------------------------------------
# episodes and metrics on hand-built runs
# ----------------------------------------------------------------------------------------------
def test_episodes_by_hand():
    assert oc.episodes([False, True, True, False, False, True, False, True]) == [(1, 3), (5, 6)]
    assert oc.episodes([True, True, False, True, False]) == [(3, 4)]  # one that starts the run is not whole
    assert oc.episodes([False, True, True, False, True, False], first=2) == [(4, 5)]
    assert oc.episodes([False] * 4) == []


def fake_run(hidden, detected, angle_deg, errors, loop="CV", seed=0, offscreen=()):
    """3 frames per revolution × 3 revolutions (fps 1.5, period 2 s); the acquisition revolution is
    all visible and detected with a 1 m error and must not count."""
    study = oc.OcclusionStudy(replicates=2, fps=1.5)
    config = study.config("panel 1.0 s", "circle", loop, seed)
    n = int(round(config.frames_per_revolution))
    hidden = np.r_[np.zeros(n, bool), hidden]
    detected = np.r_[np.ones(n, bool), detected]
    theta = np.radians(np.r_[np.zeros(n), angle_deg])
    z = 3.0 * np.cos(theta)
    u = np.full(len(z), 319.5)
    u[[n + i for i in offscreen]] = 900.0
    frames = pd.DataFrame({
        "frame": np.arange(len(z)), "hidden": hidden, "detected": detected,
        "visible_fraction": np.where(hidden, 0.0, 1.0), "partial": np.zeros(len(z), bool),
        "true_cam_x_m": 3.0 * np.sin(theta), "true_cam_y_m": np.zeros(len(z)), "true_cam_z_m": z,
        "true_u_px": u, "true_v_px": np.full(len(z), 239.5), "true_offset_px": np.full(len(z), 7.0),
        "abs_error_m": np.r_[np.ones(n), np.where(detected[n:], errors, np.nan)],
        "filter_nees": np.r_[np.full(n, 50.0), np.full(len(z) - n, 3.0)],
    })
    return TrackingResult(config=config, frames=frames)


def test_run_metrics_by_hand():
    #            frames 3..8 (measured): visible, hidden, hidden, visible (reappears), visible, visible
    run = fake_run(hidden=[0, 1, 1, 0, 0, 0], detected=[1, 0, 0, 0, 1, 1],
                   angle_deg=[1.0, 10.0, 20.0, 30.0, 2.0, 1.0], errors=[0.01, 0, 0, 0, 0.02, 0.04], offscreen=[3])
    m = oc.run_metrics(run)
    assert m["episodes"] == 1
    assert m["hidden_pointing_deg"] == pytest.approx(15.0)
    assert m["reappear_error_deg"] == pytest.approx(30.0)
    assert m["lost_pct"] == 100.0  # its true projection is off the image when it reappears
    assert m["reacquire_frames"] == 1.0  # detected again one frame after it reappears
    assert m["after_error_m"] == pytest.approx(0.03)  # frames 4 and 5 (the window runs to the end)
    assert m["pointing_error_deg"] == pytest.approx(64.0 / 6)
    assert m["visible_error_m"] == pytest.approx(0.07 / 3)
    assert m["detection_rate_pct"] == pytest.approx(50.0)
    assert m["hidden_s"] == pytest.approx(2 / 1.5 / 2)  # two hidden frames over two measured revolutions
    assert m["nees_visible"] == pytest.approx(3.0) and m["nees_hidden"] == pytest.approx(3.0)


def test_a_run_that_never_reacquires_leaves_its_reacquisition_unmeasured():
    run = fake_run(hidden=[0, 1, 0, 0, 0, 0], detected=[1, 0, 0, 0, 0, 0], angle_deg=[1, 40, 40, 40, 40, 40],
                   errors=[0.01] * 6)
    m = oc.run_metrics(run)
    assert m["episodes"] == 1 and m["lost_pct"] == 0.0
    assert math.isnan(m["reacquire_frames"]) and math.isnan(m["after_error_m"])
    table = oc.replicate_table([run, fake_run([0] * 6, [1] * 6, [1] * 6, [0.01] * 6, loop="paper")])
    assert list(table["loop"]) == ["paper", "CV"] and list(table["occlusion"]) == ["panel 1.0 s"] * 2


def test_a_config_outside_the_study_is_refused():
    with pytest.raises(ValueError, match="not one of the occlusion study's"):
        diagonal = TrackingConfig().with_(target__trajectory="diagonal", pointing__kind="paper")
        oc.replicate_table([TrackingResult(config=diagonal, frames=pd.DataFrame())])


# ----------------------------------------------------------------------------------------------
# hypotheses on hand-built replicate tables
# ----------------------------------------------------------------------------------------------
def designed_cells():
    """Per cell: (pointing error °, reappearance error °), shaped so that H1 and H2 hold and H2c does not."""
    cells = {}
    for occlusion, target, loop in itertools.product(oc.OCCLUSIONS, oc.TARGETS, oc.LOOPS):
        pointing = {"paper": 6.0, "CV": 4.0, "CA": 4.0, "IMM": 3.0}[loop]
        if target == "circle" and loop in ("CV", "CA", "IMM"):
            pointing = 3.0  # IMM no worse on the circle
        reappear = 20.0 if loop == "paper" else 5.0
        cells[(occlusion, target, loop)] = (pointing, reappear)
    return cells


def make_replicates(cells, overrides=None):
    rows = []
    for (occlusion, target, loop), (pointing, reappear) in cells.items():
        for seed in SEEDS:
            rows.append(dict(occlusion=occlusion, target=target, loop=loop, seed=seed, episodes=2,
                             pointing_error_deg=pointing + JITTER[seed], reappear_error_deg=reappear + JITTER[seed]))
    df = pd.DataFrame(rows)
    for (occlusion, target, loop, column), value in (overrides or {}).items():
        sel = (df.occlusion == occlusion) & (df.target == target) & (df.loop == loop)
        df.loc[sel, column] = value
    return df


def test_designed_replicates_give_the_designed_verdicts():
    v = oc.check_hypotheses(make_replicates(designed_cells()))
    assert list(dict.fromkeys(v["id"])) == ["H1", "H2", "H2c"]
    assert [int((v["id"] == h).sum()) for h in ("H1", "H2", "H2c")] == [6, 8, 8]
    assert (v.loc[v["id"] != "H2c", "verdict"] == stats.HOLDS).all()
    assert (v.loc[v["id"] == "H2c", "verdict"] == stats.DOES_NOT_HOLD).all()  # no effect: IMM does not lose
    assert set(v["unit"]) == {"deg"}


def test_each_outcome_is_reported_where_it_was_built():
    over = {
        ("panel 1.0 s", "circle", "CA", "reappear_error_deg"): 40.0,  # CA worse than holding: the opposite
        ("panel 1.0 s", "manoeuvring", "CV", "reappear_error_deg"): 20.0 + 0.01,  # no effect
        ("pole 0.2 s", "circle", "IMM", "pointing_error_deg"): 5.0,  # the IMM loses on the circle
        ("none", "manoeuvring", "IMM", "pointing_error_deg"): 4.0,  # no better than CV without occluders
    }
    v = oc.check_hypotheses(make_replicates(designed_cells(), over)).set_index(["id", "condition", "a", "b"])
    assert v.loc[("H1", "circle, panel 1.0 s", "CA", "paper"), "verdict"] == stats.DOES_NOT_HOLD
    assert v.loc[("H1", "circle, panel 1.0 s", "CA", "paper"), "low"] > 0
    assert v.loc[("H1", "manoeuvring, panel 1.0 s", "CV", "paper"), "verdict"] == stats.DOES_NOT_HOLD
    assert v.loc[("H2c", "circle, pole 0.2 s", "CV", "IMM"), "verdict"] == stats.HOLDS
    assert v.loc[("H2", "manoeuvring, none", "IMM", "CV"), "verdict"] == stats.DOES_NOT_HOLD
    assert v.loc[("H2", "manoeuvring, none", "IMM", "CA"), "verdict"] == stats.DOES_NOT_HOLD
    text = oc.hypotheses_markdown(v.reset_index())
    assert "the opposite is measured" in text and "no effect worth the name" in text


def test_missing_episodes_are_inconclusive_with_their_reason():
    over = {("panel 1.0 s", "manoeuvring", "IMM", "reappear_error_deg"): np.nan}
    v = oc.check_hypotheses(make_replicates(designed_cells(), over))
    row = v[(v["id"] == "H1") & (v["condition"] == "manoeuvring, panel 1.0 s") & (v["a"] == "IMM")].iloc[0]
    assert row["verdict"] == stats.INCONCLUSIVE and row["n"] == 0
    assert "occlusion episode" in oc.verdict_reason(row)


def test_a_partial_table_checks_what_it_holds():
    df = make_replicates(designed_cells())
    v = oc.check_hypotheses(df[df["target"] == "manoeuvring"])
    assert set(v["id"]) == {"H1", "H2"}
    with pytest.raises(ValueError, match="none of the cells"):
        oc.check_hypotheses(df[df["loop"] == "paper"])
