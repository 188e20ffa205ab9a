"""The buying-rule map (gimbal_lab.studies.light): its factors, runs, exposure choice, covariate,
boundary and ranking, each against a hand derivation or an independent implementation."""

import math

import numpy as np
import pandas as pd
import pytest

from gimbal_lab import stats
from gimbal_lab.studies import light as L


# ----------------------------------------------------------------------------------------------
# factors and runs
# ----------------------------------------------------------------------------------------------
def test_factors_map_their_ranges_log_uniform_where_said():
    light, rate = L.FACTORS[0], L.FACTORS[1]
    # log-uniform: the ends, and the middle of the unit interval at the geometric mean
    assert light.value(0.0) == pytest.approx(10.0) and light.value(1.0) == pytest.approx(100_000.0)
    assert light.value(0.5) == pytest.approx(1000.0, rel=1e-12)
    assert rate.value(0.5) == pytest.approx(math.sqrt(0.05 * 1.5), rel=1e-12)
    vib = L.FACTORS[4]
    assert vib.value(0.5) == pytest.approx(0.25) and vib.value(1.0) == pytest.approx(0.5)
    with pytest.raises(ValueError, match="light_lux"):
        light.value(1.5)
    # the maps share one Factor: an integer factor cannot also be log-uniform, nor a log one reach 0
    from gimbal_lab.studies.payoff import Factor

    with pytest.raises(ValueError, match="integer or log-uniform"):
        Factor("n", 1, 8, "", "n", integer=True, log=True)
    for low in (0.0, -1.0):
        with pytest.raises(ValueError, match="0 < low < high"):
            Factor("x", low, 10.0, "", "x", log=True)
    assert Factor("n", 1, 3, "", "n", integer=True).value(0.99) == 3.0  # the last level's share ends at u = 1


def test_design_hits_every_stratum_once_and_stays_in_range():
    study = L.LightStudy(points=12, replicates=2)
    d = L.design(study)
    for f in L.FACTORS:
        strata = np.floor(d[f"u_{f.name}"].to_numpy() * 12).astype(int)
        assert sorted(strata) == list(range(12)), f.name
        assert d[f.name].between(f.low, f.high).all(), f.name


@pytest.mark.parametrize("rate", [0.05, 0.3, 1.0, 1.074, 1.2, 1.5])
def test_cone_for_rate_gives_the_rate_and_caps_the_half_angle(rate):
    half, period = L.cone_for_rate(rate, 2.0)
    # the line of sight of a target circling at half-angle α with period T turns at 2π·sin α / T
    assert 2 * math.pi * math.sin(half) / period == pytest.approx(rate, rel=1e-12)
    assert half <= math.radians(20.0) + 1e-15
    if math.asin(min(1.0, rate * 2.0 / (2 * math.pi))) < math.radians(20.0):
        assert period == 2.0
    else:  # beyond the cap the half-angle stays at 20° and the period shortens
        assert half == pytest.approx(math.radians(20.0)) and period < 2.0


def test_point_config_sets_the_sensor_the_scene_and_the_pipeline():
    values = {"light_lux": 300.0, "rate_rad_s": 0.4, "range_m": 4.0, "diameter_px": 30.0, "vibration_deg": 0.2}
    c = L.point_config(values, "fixed, streak", 0.004, 100)
    assert (c.camera.noise, c.camera.light_lux, c.camera.exposure_s) == ("sensor", 300.0, 0.004)
    assert c.camera.blur == "auto"  # the exposure is integrated
    assert c.pointing.kind == "fixed" and c.estimator.sphere_method == "streak"
    assert c.platform.motion == "vibration"
    assert c.platform.vibration.rms_rad == pytest.approx(math.radians(0.2))
    # the sphere's outline on axis at the range is diameter_px across: 2·f·tan(asin(r / D))
    f = c.camera.intrinsics.fx
    assert 2 * f * math.tan(math.asin(c.target.sphere_radius_m / 4.0)) == pytest.approx(30.0, rel=1e-12)
    assert c.target.cone_range_m == 4.0
    half, period = L.cone_for_rate(0.4)
    assert c.target.cone_half_angle_rad == pytest.approx(half) and c.target.period_s == period
    assert c.camera.lens == "default" and c.camera.lens_model is not None  # the paper's distorted lens
    # what each pipeline's run is: pointing, sphere method, lens strategy (docs/design.md, decided in b52bb98)
    runs = {p: L.point_config(values, p, 0.004, 100) for p in L.PIPELINES}
    parts = {p: (c.pointing.kind, c.estimator.sphere_method, c.estimator.lens_strategy) for p, c in runs.items()}
    assert parts == {
        "active (paper)": ("paper", "circle", "ignore"), "active (best)": ("paper", "ellipse", "undistort"),
        **{f"{mount}, {p}": (mount, "streak", "undistort") for mount in ("fixed", "stabilised")
           for p in ("circle", "cone fit", "streak")}}
    # the known lens reaches the active loop, so the two active pipelines are two runs; a passive
    # mount's three pipelines are one: the streak method's own columns, the cone fit beside it
    # (alt_*) and the circle method's family (circle_*)
    assert runs["active (paper)"] != runs["active (best)"]
    assert {runs[p].estimator.extra_methods for p in L.ACTIVE} == {()}
    for mount in ("fixed", "stabilised"):
        assert runs[f"{mount}, circle"] == runs[f"{mount}, cone fit"] == runs[f"{mount}, streak"]
        assert runs[f"{mount}, circle"].estimator.extra_methods == ("circle",)
        assert [L._RUN_OF[f"{mount}, {p}"] for p in ("circle", "cone fit", "streak")] == [
            (mount, "circle_"), (mount, "alt_"), (mount, "")]
    assert {c.camera for c in runs.values()} == {c.camera}  # every pipeline sees the same camera
    with pytest.raises(ValueError, match="pipeline"):
        L.point_config(values, "gimbal", 0.004, 100)


def test_pipelines_two_active_six_passive():
    assert L.ACTIVE == ("active (paper)", "active (best)")
    assert len(L.PASSIVE) == 6 and set(L.PASSIVE) | set(L.ACTIVE) == set(L.PIPELINES)
    assert {p.split(",")[0] for p in L.PASSIVE} == {"fixed", "stabilised"}


def test_study_refuses_what_cannot_be_the_design():
    with pytest.raises(ValueError, match="calibration_seeds"):
        L.LightStudy(calibration_seeds=(100, 201))  # 201 is a test seed
    with pytest.raises(ValueError, match="exposures_ms"):
        L.LightStudy(exposures_ms=(1.0, 40.0))  # longer than a frame at 30 frames/s
    with pytest.raises(ValueError, match="points"):
        L.LightStudy(points=8)
    s = L.LightStudy(points=12, calibration_seeds=[100], exposures_ms=[16.7, 1, 4], replicates=2)
    assert s.exposures_ms == (1.0, 4.0, 16.7) and s.calibration_seeds == (100,) and s.seeds == [200, 201]
    assert len(L.RUNS) == 4 and len(L.grid(s)) == 12 * 3 * 1 * 4  # 2 active + 2 passive runs
    assert len(L.grid(L.LightStudy())) == 40 * 6 * 2 * 4


def test_study_accepts_a_fifth_of_a_revolution_and_refuses_less():
    short = L.LightStudy(points=12, calibration_seeds=(100,), replicates=2, exposures_ms=(1.0, 16.7), revolutions=0.2)
    assert short.revolutions == 0.2 and L.LightStudy().revolutions == 2.0
    assert {c.revolutions for c in L.grid(short)} == {0.2} and len(L.grid(short)) == 12 * 2 * 1 * 4
    assert {c.n_frames for c in L.grid(short) if c.target.period_s == 2.0} == {12}  # notebook 16's runs at 30 fps
    for bad in (0.199, 0.0, -1.0):
        with pytest.raises(ValueError, match=r"revolutions must be >= 0\.2 and"):
            L.LightStudy(revolutions=bad)
    for bad in (math.nan, math.inf):
        with pytest.raises(ValueError, match="revolutions"):
            L.LightStudy(revolutions=bad)
    with pytest.raises(TypeError, match="revolutions"):
        L.LightStudy(revolutions="2")
    from gimbal_lab.studies.moving_drone import MovingDroneStudy
    from gimbal_lab.studies.payoff import PayoffStudy

    assert PayoffStudy(revolutions=0.5).revolutions == 0.5  # notebook 15's size under pytest
    with pytest.raises(ValueError, match=r"revolutions must be >= 0.5"):
        PayoffStudy(revolutions=0.25)
    with pytest.raises(ValueError, match=r"revolutions must be >= 2"):  # every other study keeps two
        MovingDroneStudy(revolutions=1.5)


# ----------------------------------------------------------------------------------------------
# the exposure choice and the best pipelines (synthetic tables worked by hand)
# ----------------------------------------------------------------------------------------------
def _cal(rows):
    return pd.DataFrame(rows, columns=["point", "pipeline", "exposure_s", "seed", "error_m", "frames"])


def test_choice_pools_frames_breaks_ties_short_and_skips_exposures_without_detections():
    t = _cal([
        # A: 1 ms pools (0.25·30 + 0.75·10) / 40 = 0.375; 4 ms pools 0.375 too (exact in binary):
        # the tie goes to 1 ms. Were the runs' means averaged unweighted, 1 ms would give 0.5
        (0, "A", 0.004, 100, 0.375, 20), (0, "A", 0.004, 101, 0.375, 20),
        (0, "A", 0.001, 100, 0.25, 30), (0, "A", 0.001, 101, 0.75, 10),
        (0, "A", 0.016, 100, 0.400, 40), (0, "A", 0.016, 101, 0.400, 40),
        # B: the lowest error is at 1 ms on no frame (NaN) and must not be chosen; 16 ms has frames
        (0, "B", 0.001, 100, math.nan, 0), (0, "B", 0.001, 101, math.nan, 0),
        (0, "B", 0.016, 100, 0.050, 5), (0, "B", 0.016, 101, 0.030, 0),
        # C: never detects
        (0, "C", 0.001, 100, math.nan, 0),
    ])
    c = L.choose_exposures(t).set_index("pipeline")
    assert c.loc["A", "exposure_s"] == 0.001 and c.loc["A", "error_m"] == 0.375
    assert c.loc["B", "exposure_s"] == 0.016 and c.loc["B", "error_m"] == pytest.approx(0.050)
    assert math.isnan(c.loc["C", "exposure_s"]) and math.isnan(c.loc["C", "error_m"])


def test_choice_takes_the_lowest_not_the_shortest():
    t = _cal([(3, "A", 0.0005, 100, 0.009, 10), (3, "A", 0.002, 100, 0.003, 10), (3, "A", 0.008, 100, 0.004, 10)])
    assert L.choose_exposures(t)["exposure_s"].tolist() == [0.002]


def test_best_pipelines_by_kind_ties_to_the_first_listed():
    choices = pd.DataFrame([
        (0, "active (paper)", 0.004, 0.006), (0, "active (best)", 0.001, 0.006),
        (0, "fixed, circle", 0.001, 0.009), (0, "stabilised, cone fit", 0.0005, 0.002),
        (0, "fixed, streak", math.nan, math.nan),
        (1, "active (paper)", math.nan, math.nan), (1, "active (best)", math.nan, math.nan),
        (1, "fixed, circle", 0.001, 0.009),
    ], columns=["point", "pipeline", "exposure_s", "error_m"])
    b = L.best_pipelines(choices).set_index("point")
    assert b.loc[0, "best_active"] == "active (paper)" and b.loc[0, "exposure_active_s"] == 0.004
    assert b.loc[0, "best_passive"] == "stabilised, cone fit" and b.loc[0, "exposure_passive_s"] == 0.0005
    assert pd.isna(b.loc[1, "best_active"]) and b.loc[1, "best_passive"] == "fixed, circle"
    # a point without an active pipeline that detected gets no test runs
    index = L.test_index(L.best_pipelines(choices), L.LightStudy(points=12, replicates=2))
    assert set(index["point"]) == {0} and len(index) == 4


def _frames(detected, errors, alt_detected=None, alt_errors=None, circle_detected=None, circle_errors=None):
    n = len(detected)
    alt_detected = detected if alt_detected is None else alt_detected
    alt_errors = errors if alt_errors is None else alt_errors
    circle_detected = detected if circle_detected is None else circle_detected
    circle_errors = errors if circle_errors is None else circle_errors
    return pd.DataFrame({"frame": np.arange(n), "revolution": [0] * 2 + [1] * (n - 2), "detected": detected,
                         "abs_error_m": errors, "alt_detected": alt_detected, "alt_abs_error_m": alt_errors,
                         "circle_detected": circle_detected, "circle_abs_error_m": circle_errors})


class _Result:
    def __init__(self, frames):
        self.frames = frames


def test_run_errors_read_the_main_and_the_alt_columns_over_measured_frames():
    f = _frames([True, True, True, False, True], [9.0, 9.0, 0.002, 5.0, 0.004],
                [True, True, True, True, False], [9.0, 9.0, 0.001, 0.003, 7.0],
                [True, True, False, True, True], [9.0, 9.0, 8.0, 0.006, 0.010])
    e = L.run_errors(f, "fixed")
    assert e["fixed, streak"] == (pytest.approx(0.003), 2)  # frames 2 and 4 (0 and 1 acquire)
    assert e["fixed, cone fit"] == (pytest.approx(0.002), 2)  # frames 2 and 3
    assert e["fixed, circle"] == (pytest.approx(0.008), 2)  # frames 3 and 4
    assert L.run_errors(f, "active (best)") == {"active (best)": (pytest.approx(0.003), 2)}


def test_a_run_inside_its_first_revolution_measures_its_second_half():
    # notebook 16's half revolution: every frame in revolution 0, so the map measures frames 3-5 of 6
    f = _frames([True] * 6, [9.0, 9.0, 9.0, 0.002, 0.004, 0.006], [True] * 6, [0.0] * 6, [True] * 6, [0.0] * 6)
    f["revolution"] = 0
    assert L.run_errors(f, "fixed")["fixed, streak"] == (pytest.approx(0.004), 3)
    # once a run reaches its second revolution only that counts, however short the first
    f["revolution"] = [0, 1, 1, 1, 1, 1]
    assert L.run_errors(f, "fixed")["fixed, streak"] == (pytest.approx((9.0 + 9.0 + 0.012) / 5), 5)


def test_responses_pair_on_the_frames_both_detected():
    index = pd.DataFrame([(0, 200, "active", "active (best)", 0.004), (0, 200, "passive", "fixed, cone fit", 0.001)],
                         columns=["point", "seed", "side", "pipeline", "exposure_s"])
    active = _frames([True] * 5, [0, 0, 0.001, 0.002, 0.100], alt_errors=[0, 0, 0.010, 0.020, 0.030])
    passive = _frames([True] * 5, [0, 0, 0.009, 0.009, 0.009], [True, True, True, True, False],
                      [0, 0, 0.005, 0.005, 0.005])
    r = L.response_table(index, [_Result(active), _Result(passive)]).iloc[0]
    # active (best) is its run's own column, the cone fit the alt column; the common frames are 2 and 3
    assert r["active_m"] == pytest.approx(0.0015) and r["passive_m"] == pytest.approx(0.005)
    assert r["delta_m"] == pytest.approx(-0.0035) and r["common_rate"] == pytest.approx(2 / 3)
    # runs inside their first revolution pair on their second halves (frames 2-4 of 5: common 2 and 3)
    for f in (active, passive):
        f["revolution"] = 0
    r = L.response_table(index, [_Result(active), _Result(passive)]).iloc[0]
    assert r["delta_m"] == pytest.approx(-0.0035) and r["common_rate"] == pytest.approx(2 / 3)


# ----------------------------------------------------------------------------------------------
# the covariate
# ----------------------------------------------------------------------------------------------
def _threshold_lux(t_s):
    """The light at which the auto-gain needs exactly K_max at exposure t (hand closed form):
    255 / (η · E·T/(4N²·683) · A · t · λ/(hc)) = K_max, IMX273 at f/2.8."""
    h, c, lam = 6.62607015e-34, 299_792_458.0, 555e-9
    sat = round(10 ** (40.2 / 10))
    k_max = 255.0 / sat * 10 ** (48 / 20)
    per_lux = 0.65 * 0.9 / (4 * 2.8**2 * 683.0) * (3.45e-6) ** 2 * t_s * lam / (h * c)
    return 255.0 / (k_max * per_lux)


def test_shortest_exposure_matches_the_closed_form_either_side_of_each_threshold():
    E = (0.0005, 0.001, 0.002, 0.004, 0.008, 0.0167)
    for i, t in enumerate(E):
        lux = _threshold_lux(t)
        assert L.shortest_exposure_s(lux * 1.001, E) == t
        below = L.shortest_exposure_s(lux * 0.999, E)
        assert (below == E[i + 1]) if i + 1 < len(E) else math.isnan(below)
    assert _threshold_lux(0.0167) == pytest.approx(2.75, abs=0.02)  # the set covers 10 lx and up
    d = pd.DataFrame({"point": [0], "light_lux": [_threshold_lux(0.004) * 1.01], "rate_rad_s": [0.5]})
    s = L.streak_covariate_px(d, L.LightStudy()).iloc[0]
    assert s["t_min_s"] == 0.004 and s["s_px"] == pytest.approx(0.5 * 554.2563 * 0.004, rel=1e-5)


def test_full_well_light_matches_the_closed_form_and_clips_above_it():
    from gimbal_lab.sensor import SensorModel

    h, c, lam = 6.62607015e-34, 299_792_458.0, 555e-9
    sat = round(10 ** (40.2 / 10))  # 10,471 e-
    for t in (0.0005, 0.004, 0.0167):
        per_lux = 0.65 * 0.9 / (4 * 2.8**2 * 683.0) * (3.45e-6) ** 2 * t * lam / (h * c)  # e- per lx (hand)
        lux = L.full_well_lux(t)
        assert lux == pytest.approx(sat / per_lux, rel=1e-9)
        # just above it the auto-gain is held at K_min and a white pixel fills the well; just below it does not
        for factor, fills in ((1.001, True), (0.999, False)):
            model = SensorModel("IMX273", light_lux=lux * factor, f_number=2.8)
            assert (model.electrons_at_full_reflectance(t) > model.figures.saturation_e) == fills
    assert L.full_well_lux(0.0005) == pytest.approx(23_060, rel=1e-3)  # the shortest exposure of E


# ----------------------------------------------------------------------------------------------
# the boundary
# ----------------------------------------------------------------------------------------------
def test_logistic_fit_matches_statsmodels():
    sm = pytest.importorskip("statsmodels.api")
    rng = np.random.default_rng(3)
    x = rng.normal(0, 1.5, 80)
    y = (rng.random(80) < 1 / (1 + np.exp(-(0.7 + 2.0 * x)))).astype(float)
    b0, b1 = L.fit_logistic(x, y)
    ref = sm.Logit(y, sm.add_constant(x)).fit(disp=0).params
    assert (b0, b1) == pytest.approx(tuple(ref), rel=1e-6)


def test_boundary_recovers_a_known_crossing():
    # pays with probability 1/(1 + (s*/s)^4), s* = 3 px: the crossing of the logit on log s
    rng = np.random.default_rng(40)
    s = np.exp(rng.uniform(np.log(0.1), np.log(100.0), 400))
    pays = rng.random(400) < 1 / (1 + (3.0 / s) ** 4)
    b = L.fit_boundary(s, pays, bootstrap=200, seed=1)
    assert b.low_px < 3.0 < b.high_px and b.s_px == pytest.approx(3.0, rel=0.15)  # 400 points: within 15 %
    assert b.slope > 0 and b.pays + b.does_not == 400 and b.resamples == 200
    assert "more than" in L.boundary_sentence(b)
    # the other way round: pays below s*
    b = L.fit_boundary(s, ~pays, bootstrap=50, seed=1)
    assert b.slope < 0 and b.s_px == pytest.approx(3.0, rel=0.15)


def test_boundary_under_separation_and_on_one_side():
    b = L.fit_boundary([0.1, 0.2, 0.4, 2.0, 5.0], [False, False, False, True, True], bootstrap=100, seed=0)
    assert b.s_px == pytest.approx(math.sqrt(0.4 * 2.0))  # the gap's middle on log s
    assert 0.4 <= b.low_px <= b.high_px <= 2.0 and b.slope == math.inf
    one = L.fit_boundary([0.1, 1.0, 3.0], [False, False, False], bootstrap=10)
    assert math.isnan(one.s_px) and "does not pay" in one.note and "no boundary" in L.boundary_sentence(one)


# ----------------------------------------------------------------------------------------------
# the ranking: rank-based, so one runaway point cannot zero it
# ----------------------------------------------------------------------------------------------
def test_ranking_keeps_the_driving_factor_first_despite_a_runaway_point():
    from gimbal_lab.studies.payoff import unit_design

    u = unit_design(40, 40, k=5)
    rng = np.random.default_rng(0)
    y = 5.0 * u[:, 1] + 0.3 * rng.normal(size=40)
    y[np.argmin(u[:, 1])] = 1e6  # one runaway point, where the driver is smallest
    r = L.rank_factors(u, y, bootstrap=200)
    assert r["factor"].iloc[0] == "rate_rad_s" and r["s1"].iloc[0] > 0.5
    assert r["s1"].iloc[1:].max() < 0.3


# ----------------------------------------------------------------------------------------------
# verdicts per point and the points' classes
# ----------------------------------------------------------------------------------------------
def test_point_verdicts_and_classes():
    study = L.LightStudy(points=12, replicates=3)
    d = L.design(study)
    rows = []
    for p in range(12):
        for seed, noise in zip(study.seeds, (0.0, 0.0001, -0.0001)):
            active, passive = (0.002 + noise, 0.010) if p < 6 else (0.010 + noise, 0.002)
            if p >= 10:  # two marginal points: each holds alone (p = 0.031), neither in the family (Holm: 0.062)
                active, passive = 0.002 + 0.0025 * {200: 1, 201: -1, 202: 0}[seed], 0.010
            rows.append(dict(point=p, seed=seed, best_active="active (best)", best_passive="fixed, circle",
                             active_m=active, passive_m=passive, common_rate=1.0, delta_m=active - passive))
    v = L.point_verdicts(pd.DataFrame(rows), d)
    assert len(v) == 12 and (v["id"] == "BP2″").all()
    best = pd.DataFrame({"point": range(12), "best_active": "active (best)", "best_passive": "fixed, circle"})
    pts = L.point_table(v, d, best, L.streak_covariate_px(d, study))
    assert (pts.loc[pts.point < 6, "class"] == "pays").all()
    assert (pts.loc[pts.point.between(6, 9), "class"] == "does not").all()
    marginal = pts[pts.point >= 10]
    assert (marginal["verdict"] == stats.HOLDS).all() and (marginal["verdict_holm"] == stats.INCONCLUSIVE).all()
    assert (marginal["class"] == "open").all()  # the class is the family's verdict, not the comparison's


# ----------------------------------------------------------------------------------------------
# the report and its figures, from synthetic runs (no rendering)
# ----------------------------------------------------------------------------------------------
def _fake_run(error_m, alt_error_m, n=10, detected=True):
    return _Result(_frames([detected] * n, [error_m] * n, alt_errors=[alt_error_m] * n))


def _fake_map(study):
    """Calibration and test runs whose errors are worked out by hand: at points 0-5 the active
    pipelines err 2 mm and the passive ones 8 mm (the gimbal pays), elsewhere the other way; every
    pipeline's error grows with the exposure's distance from 4 ms, so each chooses 4 ms."""
    index = L.calibration_index(study)
    calibration = []
    for r in index.itertuples():
        pays = r.point < 6
        base = (0.002 if pays else 0.008) if r.run.startswith("active") else (0.008 if pays else 0.002)
        extra = abs(r.exposure_s - 0.004)
        calibration.append(_fake_run(base + extra, base + extra + 0.0005))  # alt: 0.5 mm worse
    best = L.best_pipelines(L.choose_exposures(L.calibration_table(calibration, study)))
    tests = L.test_index(best, study)
    results = []
    for r in tests.itertuples():
        pays = r.point < 6
        e = (0.002 if pays else 0.008) if r.side == "active" else (0.008 if pays else 0.002)
        e += 0.0001 * (r.seed - 200)  # replicates differ
        results.append(_fake_run(e, e))
    return calibration, tests, results


def test_report_names_each_pipelines_exposure_and_draws_the_map(tmp_path):
    report_module = pytest.importorskip("gimbal_lab.studies.report")
    study = L.LightStudy(points=12, calibration_seeds=(100,), replicates=3, exposures_ms=(1, 4, 16.7), bootstrap=50)
    calibration, tests, results = _fake_map(study)
    assert set(tests["pipeline"]) == {"active (paper)", "fixed, circle"}  # the main columns are 0.5 mm better
    assert set(tests["exposure_s"]) == {0.004}
    tables = L.analyse(calibration, tests, results, study)
    points = tables["points"]
    assert (points.loc[points.point < 6, "class"] == "pays").all()
    assert (points.loc[points.point >= 6, "class"] == "does not").all()
    assert points["delta_m"].to_numpy() == pytest.approx(np.where(points.point < 6, -0.006, 0.006))
    report = L.make_report(calibration, tests, results, study)
    written = report_module.write(tmp_path, report)
    names = {p.name for p in written}
    assert {"claims.md", "choices.csv", "points.csv", "verdicts.csv", "boundary.csv", "map.png"} <= names
    claims = (tmp_path / "claims.md").read_text()
    # every pipeline's chosen exposure, per point: 4 ms in each of the eight columns
    row = next(line for line in claims.splitlines() if line.startswith("| 0 | "))
    assert row.split(" | ")[1:] == ["4"] * 7 + ["4 |"]
    assert "pays at 6** of 12 points" in claims and "does not at 6**" in claims


def test_buying_map_draws_each_class_and_the_rule_with_its_band():
    import matplotlib

    matplotlib.use("Agg")
    from gimbal_lab.plotting import light as pl

    points = pd.DataFrame({"s_px": [0.1, 0.5, 2.0, 5.0], "light_lux": [10, 100, 1000, 1e4],
                           "class": ["does not", "open", "pays", "pays"], "delta_m": [0.002, 0.0, -0.003, -0.004],
                           "delta_low_m": [0.001, -0.001, -0.004, -0.005], "delta_high_m": [0.003, 0.001, -0.002, -0.003]})
    b = L.Boundary(0.8, 0.3, 1.5, 2.0, 2, 1, 100, "the gimbal pays above s*")
    ax = pl.plot_buying_map(points, b)
    assert ax.get_xscale() == "log" and ax.get_yscale() == "log"
    line = [ln for ln in ax.lines if ln.get_label().startswith("s* =")][0]
    assert line.get_xdata()[0] == pytest.approx(0.8)
    band = ax.patches[0]  # the 95 % band, from low_px to high_px
    assert band.get_x() == pytest.approx(0.3) and band.get_x() + band.get_width() == pytest.approx(1.5)
    labels = ax.get_legend_handles_labels()[1]
    assert "gimbal pays (2)" in labels and "gimbal does not pay (1)" in labels and "open (1)" in labels
    ax2 = pl.plot_delta_vs_streak(points, b)
    drawn = sorted(float(y) for ln in ax2.lines if ln.get_marker() == "o" for y in ln.get_ydata())
    assert drawn == pytest.approx([-4.0, -3.0, 0.0, 2.0])  # Δ in mm
    none = pl.plot_buying_map(points, L.Boundary(math.nan, math.nan, math.nan, math.nan, 2, 0, 0, "every point pays"))
    assert not [ln for ln in none.lines if ln.get_label().startswith("s* =")] and none.get_title() == "every point pays"


def test_command_line_refuses_a_map_it_cannot_run_before_any_run(tmp_path, capsys, monkeypatch):
    from gimbal_lab import cli, runner
    from gimbal_lab.studies import STUDIES

    assert STUDIES["light"] == "gimbal_lab.studies.light"
    monkeypatch.setattr(runner, "run", lambda *a, **k: pytest.fail("a run was computed"))
    config = tmp_path / "light.toml"
    config.write_text("[light]\ncalibration_seeds = [100, 200]\n")
    for argv, says in ((["--config", str(config)], "calibration_seeds [200] are also test seeds"),
                       (["--points", "11"], "--points"),
                       (["--replicates", "1"], "replicates")):
        with pytest.raises(SystemExit) as exc:
            cli.main(["run", "light", "--out", str(tmp_path / "out"), *argv])
        err = capsys.readouterr().err
        assert exc.value.code == 2 and says in err and err.count("\n") == 1, err  # one line


def test_the_shipped_config_is_the_registered_full_size():
    from pathlib import Path

    shipped = L.LightStudy.from_toml(Path(__file__).resolve().parents[1] / "data" / "studies" / "light.toml")
    assert shipped == L.LightStudy()
    assert (shipped.points, shipped.calibration_seeds, shipped.seeds, shipped.design_seed) == (40, (100, 101),
                                                                                             [200, 201, 202, 203, 204], 40)
    assert shipped.exposures_ms == (0.5, 1.0, 2.0, 4.0, 8.0, 16.7)


def test_too_few_points_with_a_response_leave_the_ranking_out_not_the_report():
    study = L.LightStudy(points=12, calibration_seeds=(100,), replicates=3, exposures_ms=(1, 4, 16.7), bootstrap=50)
    calibration, tests, results = _fake_map(study)
    keep = tests["point"] < 3  # only three points tested
    tables = L.analyse(calibration, tests[keep].reset_index(drop=True),
                       [r for r, k in zip(results, keep) if k], study)
    assert tables["ranking"]["s1"].isna().all() and int(tables["ranking"]["points"].iloc[0]) == 3
    assert "Not ranked: rbd_fast needs at least 12 points" in L.claims_markdown(tables, study)


def test_the_command_runs_the_calibration_then_the_tests_its_choices_call_for(tmp_path, monkeypatch):
    from gimbal_lab import runner

    study = L.LightStudy(points=12, calibration_seeds=(100,), replicates=3, exposures_ms=(1, 4, 16.7), bootstrap=50)
    calibration, tests, results = _fake_map(study)
    calls = []

    def fake_run(configs, **kwargs):
        calls.append((list(configs), kwargs["desc"]))
        return calibration if len(calls) == 1 else results

    monkeypatch.setattr(runner, "run", fake_run)
    out = L.run_study(study, tmp_path, progress=False)
    assert [desc for _, desc in calls] == ["light map: calibration", "light map: test"]
    assert calls[0][0] == L.grid(study)  # the calibration grid first, then the runs its choices call for
    assert calls[1][0] == L.test_configs(tests, study)
    expected = L.analyse(calibration, tests, results, study)["verdicts"]
    assert list(out["verdicts"]["verdict_holm"]) == list(expected["verdict_holm"]) and len(expected) == 12
    assert (tmp_path / "light" / "claims.md").is_file() and (tmp_path / "light" / "points.csv").is_file()


def test_a_calibration_table_refuses_results_that_are_not_its_grids():
    study = L.LightStudy(points=12, calibration_seeds=(100,), replicates=2, exposures_ms=(1, 16.7))
    calibration, _, _ = _fake_map(study)
    for results in (calibration[:-1], calibration + calibration[:1]):
        with pytest.raises(ValueError, match=f"expected {len(calibration)} calibration runs"):
            L.calibration_table(results, study)
    from gimbal_lab.studies import exposure as X

    small = X.ExposureStudy(calibration_seeds=(100,), replicates=2, exposures_ms=(1, 16.7), revolutions=0.25)
    n = len(X.calibration_index(small))
    with pytest.raises(ValueError, match=f"expected {n} calibration runs"):
        X.calibration_table(calibration[: n - 1], small)
    table = X.calibration_table(calibration[:n], small)  # the condition is the choice code's "point"
    assert list(table["point"].unique()) == list(X.conditions()["condition"])
