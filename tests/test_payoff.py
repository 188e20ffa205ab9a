"""The payoff map (gimbal_lab.studies.payoff): its design, configs, responses, ranking and boundary,
each against a case worked out by hand or a synthetic response with a known answer."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from gimbal_lab import stats
from gimbal_lab.studies import payoff as po
from gimbal_lab.studies.paper import replicate_phase_s


# ----------------------------------------------------------------------------------------------
# design
# ----------------------------------------------------------------------------------------------
@pytest.mark.parametrize("points", [12, 13, 64])
def test_the_latin_hypercube_hits_each_of_a_factors_strata_once(points):
    u = po.unit_design(points, seed=28)
    assert u.shape == (points, len(po.FACTORS))
    strata = np.floor(u * points).astype(int)  # stratum i is [i/N, (i+1)/N)
    for j in range(u.shape[1]):
        assert sorted(strata[:, j]) == list(range(points)), po.FACTORS[j].name
    assert np.array_equal(u, po.unit_design(points, seed=28))  # seeded
    assert not np.array_equal(u, po.unit_design(points, seed=29))


def test_every_factor_value_lies_in_its_range_and_integer_levels_share_the_interval():
    table = po.design(po.PayoffStudy(points=64, replicates=2))
    for f in po.FACTORS:
        values = table[f.name].to_numpy()
        assert values.min() >= f.low and values.max() <= f.high, f.name
        u = table[f"u_{f.name}"].to_numpy()
        if f.integer:  # latency: 1 on [0, 1/3), 2 on [1/3, 2/3), 3 on [2/3, 1)
            assert set(values) == {1.0, 2.0, 3.0}
            assert np.array_equal(values, 1.0 + np.floor(3.0 * u))
        else:  # linear: the ends of the unit interval are the range's ends
            assert values == pytest.approx(f.low + (f.high - f.low) * u, rel=1e-12, abs=1e-12)
    latency = po.FACTORS[po.FACTOR_NAMES.index("latency_frames")]
    assert latency.value([0.0, 0.3333, 0.3334, 0.9999, 1.0]).tolist() == [1.0, 1.0, 2.0, 3.0, 3.0]
    with pytest.raises(ValueError, match="latency_frames"):
        latency.value([1.2])


def test_a_points_configs_carry_its_factor_values():
    study = po.PayoffStudy(points=12, replicates=2)
    values = {"diameter_px": 40.0, "range_m": 2.5, "off_axis_deg": 12.0, "k1": 0.1, "fps": 45.0,
              "latency_frames": 2.0, "noise_std": 3.5, "exposure_ms": 8.0}
    configs = {p: po.point_config(values, p, seed=3, study=study) for p in po.PIPELINES}
    for c in configs.values():
        assert c.camera.lens.k1 == 0.1 and c.camera.lens.k2 == 0.0 and c.camera.lens.p1 == 0.0
        assert (c.camera.fps, c.camera.latency_frames, c.camera.noise_std) == (45.0, 2, 3.5)
        assert c.camera.exposure_s == pytest.approx(0.008, rel=1e-15)
        assert c.target.kind == "sphere" and c.target.trajectory == "cone"
        assert c.target.cone_range_m == 2.5 and c.target.cone_half_angle_rad == pytest.approx(math.radians(12.0))
        # by hand: the on-axis outline of radius r at D spans 2 f tan(asin(r / D)) px
        f = c.camera.intrinsics.fx
        assert 2 * f * math.tan(math.asin(c.target.sphere_radius_m / 2.5)) == pytest.approx(40.0, rel=1e-12)
        assert c.seed == 3 and c.target.start_phase_s == replicate_phase_s(3, 2.0)
    paper, best, passive = (configs[p] for p in po.PIPELINES)
    assert (paper.pointing.kind, paper.estimator.sphere_method, paper.estimator.lens_strategy) == ("paper", "circle", "ignore")
    assert (best.pointing.kind, best.estimator.sphere_method, best.estimator.lens_strategy) == ("paper", "ellipse", "undistort")
    assert (passive.pointing.kind, passive.estimator.sphere_method, passive.estimator.lens_strategy) == \
        ("stabilised", "ellipse", "undistort")


def test_the_grid_runs_every_point_seed_and_pipeline_in_the_index_order():
    study = po.PayoffStudy(points=12, replicates=2, first_seed=4)
    configs, index, table = po.grid(study), po.run_index(study), po.design(study)
    assert len(configs) == len(index) == 12 * 2 * 3
    for c, r in zip(configs, index.itertuples()):
        row = table.iloc[r.point]
        assert c.seed == r.seed and c.target.cone_range_m == row["range_m"] and c.camera.fps == row["fps"]
    assert set(index["seed"]) == {4, 5}


def test_the_study_refuses_bad_sizes_naming_the_field():
    with pytest.raises(ValueError, match="points"):
        po.PayoffStudy(points=11)
    with pytest.raises(ValueError, match="replicates"):
        po.PayoffStudy(replicates=1)
    with pytest.raises(ValueError, match="harmonics"):
        po.PayoffStudy(points=12, harmonics=3)


def test_the_command_line_refuses_the_same_points_as_the_study():
    """``--points`` checks its bound while the parser is built, without importing the study; the
    bound it names must be the study's own."""
    from gimbal_lab.studies.cli import PAYOFF_MIN_POINTS

    assert PAYOFF_MIN_POINTS == po.MIN_POINTS
    po.PayoffStudy(points=PAYOFF_MIN_POINTS)  # accepted


# ----------------------------------------------------------------------------------------------
# responses
# ----------------------------------------------------------------------------------------------
def _frames(detected, errors, revolution=(0, 0, 1, 1, 1, 1)):
    return pd.DataFrame({"frame": np.arange(len(detected)), "revolution": revolution,
                         "detected": detected, "abs_error_m": errors})


def test_the_errors_are_compared_on_the_measured_frames_all_pipelines_detected():
    nan = math.nan
    frames = {  # frames 0-1 are acquisition; all three detect frames 2 and 5 only
        "active (paper)": _frames([1, 1, 1, 1, 0, 1], [9.0, 9.0, 0.010, 0.500, nan, 0.030]),
        "active (best)": _frames([1, 1, 1, 0, 1, 1], [9.0, 9.0, 0.002, nan, 0.700, 0.004]),
        "best passive": _frames([1, 0, 1, 1, 1, 1], [9.0, nan, 0.003, 0.900, 0.800, 0.005]),
    }
    out = po.common_frame_errors(frames)
    assert out["active (paper)"] == pytest.approx((0.020, 0.5))
    assert out["active (best)"] == pytest.approx((0.003, 0.5))
    assert out["best passive"] == pytest.approx((0.004, 0.5))
    frames["best passive"] = _frames([1, 1, 0, 0, 0, 0], [0.1, 0.1, nan, nan, nan, nan])
    assert math.isnan(po.common_frame_errors(frames)["active (best)"][0])  # no common frame
    frames["best passive"] = _frames([1] * 5, [0.1] * 5, revolution=(0, 1, 1, 1, 1))
    with pytest.raises(ValueError, match="different measured frames"):
        po.common_frame_errors(frames)


def test_runs_inside_their_first_revolution_are_compared_on_their_second_halves():
    # notebook 15's half revolution under pytest: every frame in revolution 0; frames 3-5 of 6 count
    nan, zero = math.nan, (0,) * 6
    frames = {
        "active (paper)": _frames([1, 1, 1, 1, 0, 1], [0.1, 0.1, 0.1, 0.010, nan, 0.030], zero),
        "active (best)": _frames([1, 1, 1, 1, 1, 1], [0.1, 0.1, 0.1, 0.002, 0.700, 0.004], zero),
        "best passive": _frames([0, 0, 0, 1, 1, 1], [nan, nan, nan, 0.003, 0.800, 0.005], zero),
    }
    out = po.common_frame_errors(frames)
    assert out["active (paper)"] == pytest.approx((0.020, 2 / 3))  # frames 3 and 5
    assert out["active (best)"] == pytest.approx((0.003, 2 / 3))
    assert out["best passive"] == pytest.approx((0.004, 2 / 3))
    # the rule is payoff's and the light map's alike; at two revolutions it is revolution >= 1
    assert list(po.measured_frames(frames["best passive"])["frame"]) == [3, 4, 5]
    assert list(po.measured_frames(_frames([1] * 4, [0.0] * 4, (0, 0, 1, 1)))["frame"]) == [2, 3]


class _Run:
    def __init__(self, frames):
        self.frames = frames


def test_the_response_table_pairs_the_pipelines_of_a_point_and_seed():
    study = po.PayoffStudy(points=12, replicates=2)
    index = po.run_index(study)
    error = {"active (paper)": 0.030, "active (best)": 0.010, "best passive": 0.015}
    runs = [_Run(_frames([1] * 6, [error[r.pipeline] + 0.001 * r.point + 0.0001 * r.seed] * 6))
            for r in index.itertuples()]
    table = po.response_table(runs, study)
    assert len(table) == 24 and set(table["common_rate"]) == {1.0}
    assert table["delta_best_m"].to_numpy() == pytest.approx(np.full(24, -0.005), abs=1e-15)
    assert table["delta_paper_m"].to_numpy() == pytest.approx(np.full(24, 0.015), abs=1e-15)
    row = table[(table["point"] == 3) & (table["seed"] == 1)].iloc[0]
    assert row["best passive"] == pytest.approx(0.015 + 0.003 + 0.0001)
    assert row["range_m"] == po.design(study).iloc[3]["range_m"]
    with pytest.raises(ValueError, match="expected 72 runs"):
        po.response_table(runs[:-1], study)


def test_each_point_gets_bp1_and_bp2_with_holm_over_the_whole_map():
    # point 0: active (best) is 5 mm better in every replicate (holds); point 1: 5 mm worse
    rows = []
    for point, shift in ((0, -0.005), (1, +0.005)):
        for seed, jitter in enumerate((0.0, 0.0002, -0.0001, 0.0001)):
            rows.append({"point": point, "seed": seed, **{n: 0.0 for n in po.FACTOR_NAMES},
                         "active (paper)": 0.050 + jitter, "active (best)": 0.020 + shift + jitter,
                         "best passive": 0.020})
    v = po.point_verdicts(pd.DataFrame(rows))
    assert len(v) == 4 and set(v["id"]) == {"BP1", "BP2"}
    bp2 = v[v["id"] == "BP2"].set_index("point")
    assert bp2.loc[0, "verdict"] == stats.HOLDS and bp2.loc[1, "verdict"] == stats.DOES_NOT_HOLD
    assert bp2.loc[0, "difference"] == pytest.approx(-0.005 + 0.0002 / 4, abs=1e-12)
    expected = stats.holm(v.drop(columns=["p_holm", "verdict_holm"]))  # one family of all four
    assert v["p_holm"].to_numpy() == pytest.approx(expected["p_holm"].to_numpy())
    assert (v["p_holm"] >= v["p_value"]).all()
    points = po.point_table(v, pd.DataFrame({"point": [0, 1]}))
    assert points["class"].tolist() == ["pays off", "does not"]


# ----------------------------------------------------------------------------------------------
# ranking and boundary
# ----------------------------------------------------------------------------------------------
@pytest.mark.parametrize("points", [12, 24, 64])
def test_the_ranking_puts_the_one_influential_factor_first(points):
    u = po.unit_design(points, seed=5)
    y = 5.0 * u[:, 3] + np.random.default_rng(1).normal(0.0, 0.2, points)  # only k1 matters
    ranking = po.rank_factors(u, y, bootstrap=200, seed=2)
    assert ranking["factor"].iloc[0] == "k1"
    top = ranking.iloc[0]
    assert top["s1"] > 0.7 and top["s1_low"] > ranking["s1"].iloc[1:].max()  # its interval clears the rest
    assert (ranking["s1_low"] < ranking["s1"]).all() and (ranking["s1"] < ranking["s1_high"]).all()  # not collapsed
    assert ranking["rank"].tolist() == list(range(1, 9)) and ranking["points"].iloc[0] == points


def test_the_ranking_leaves_out_points_without_a_response_and_needs_enough():
    u = po.unit_design(14, seed=5)
    y = 5.0 * u[:, 0]
    y[[2, 7]] = np.nan
    assert po.rank_factors(u, y, bootstrap=50)["points"].iloc[0] == 12
    y[3] = np.nan
    with pytest.raises(ValueError, match="at least 12 points"):
        po.rank_factors(u, y, bootstrap=50)


def test_the_boundary_is_where_a_synthetic_response_breaks_even():
    # Δ = 2 (a − 0.3)(1 + b): zero on the line a = 0.3 whatever b; the surface fits it exactly
    u = po.unit_design(16, seed=9, k=2)
    y = 2.0 * (u[:, 0] - 0.3) * (1.0 + u[:, 1])
    s = po.fit_surface(u[:, 0], u[:, 1], y, "x", "y")
    assert s.coef == pytest.approx((-0.6, 2.0, -0.6, 2.0), abs=1e-10)
    assert s.r2 == pytest.approx(1.0, abs=1e-12) and s.crosses_zero
    ua, ub, z = s.grid(11)
    assert np.all(z[:, ua < 0.3 - 1e-9] < 0) and np.all(z[:, ua > 0.3 + 1e-9] > 0)
    # along b: the zero is at a = 0.3, so b ↦ Δ has no zero in [0, 1] except on that line
    assert s(0.3, ub) == pytest.approx(np.zeros_like(ub), abs=1e-10)
    # a surface of one sign has no break-even inside the box
    flat = po.fit_surface(u[:, 0], u[:, 1], 0.01 + u[:, 0] * u[:, 1], "x", "y")
    assert not flat.crosses_zero
    tilted = po.fit_surface(u[:, 0], u[:, 1], u[:, 0] + u[:, 1] - 1.0, "x", "y")  # zero on b = 1 − a
    assert tilted.break_even_ub([0.2, 0.5]) == pytest.approx([0.8, 0.5], abs=1e-10)
    with pytest.raises(ValueError, match="at least 5 points"):
        po.fit_surface(u[:4, 0], u[:4, 1], y[:4])


@pytest.mark.parametrize("k1", [po.FACTORS[po.FACTOR_NAMES.index("k1")].low, po.FACTORS[po.FACTOR_NAMES.index("k1")].high])
def test_every_pixel_has_a_preimage_through_the_lens_at_either_end_of_the_k1_range(k1):
    # the renderer and the known-lens estimator undistort every pixel of the image: with k2 = 0 the
    # barrel model folds at r² = 1/(3|k1|), where the distorted radius peaks at (2/3)/√(3|k1|), so the
    # image's corner (0.7205 normalised) needs k1 > −0.2855; a wider range raises UndistortionError here
    from gimbal_lab.camera import undistort_pixels

    values = {"diameter_px": 30.0, "range_m": 3.0, "off_axis_deg": 10.0, "k1": k1, "fps": 30.0,
              "latency_frames": 1.0, "noise_std": 2.0, "exposure_ms": 0.0}
    camera = po.point_config(values, "best passive", seed=0, study=po.PayoffStudy(points=12, replicates=2)).camera
    u, v = np.meshgrid(np.arange(camera.width, dtype=float), np.arange(camera.height, dtype=float))
    src = undistort_pixels(np.column_stack((u.ravel(), v.ravel())), camera.intrinsics, camera.lens_model)
    assert np.isfinite(src).all()
    corner = math.hypot(camera.intrinsics.cx, camera.intrinsics.cy) / camera.intrinsics.fx
    assert k1 > 0 or (2.0 / 3.0) / math.sqrt(3.0 * abs(k1)) > corner  # the hand bound agrees
