"""The moving drone with exposure as a choice (``gimbal_lab.studies.exposure``; docs/design.md,
"Exposure as a choice, and a buying rule", the re-registered claims and their *As built* note).

Oracles: the registered design written out by hand (conditions, seeds, run counts, what each run
is); synthetic frame tables whose pairs and verdicts are worked by hand; ``stats.less_than`` and
``stats.against_every`` themselves are tested in tests/test_stats.py.
"""

import math

import numpy as np
import pandas as pd
import pytest

from gimbal_lab import stats
from gimbal_lab.studies import exposure as X
from gimbal_lab.studies import light as L
from gimbal_lab.studies.moving_drone import MovingDroneStudy

SMALL = dict(calibration_seeds=(100,), replicates=2, exposures_ms=(1.0, 16.7), revolutions=0.25)


def test_conditions_and_runs_are_the_registered_ones():
    c = X.conditions()
    assert list(zip(c["motion"], c["light_lux"])) == [("hover", 300.0), ("hover", 10_000.0), ("vibration", 300.0),
                                                        ("vibration", 10_000.0), ("flight", 300.0),
                                                        ("flight", 10_000.0)]
    study = X.ExposureStudy()
    assert study.seeds == [200, 201, 202, 203, 204] and study.calibration_seeds == (100, 101)
    assert study.exposures_ms == (0.5, 1.0, 2.0, 4.0, 8.0, 16.7) and study.revolutions == 2.0
    assert len(X.grid()) == 6 * 6 * 2 * 4 == 288
    small = X.ExposureStudy(**SMALL)
    grid, index = X.grid(small), X.calibration_index(small)
    assert len(grid) == len(index) == 6 * 2 * 1 * 4
    assert {c.revolutions for c in grid} == {0.25} and {c.seed for c in grid} == {100}
    for r, c in zip(index.itertuples(), grid):
        motion, lux = X.conditions().set_index("condition").loc[r.condition]
        assert c.platform.motion == motion and c.camera.light_lux == lux and c.camera.noise == "sensor"
        assert c.camera.exposure_s == r.exposure_s and c.camera.lens == "default" and c.camera.readout_s == 0
        assert c.target.kind == "sphere" and c.target.trajectory == "circular"
        kind, method, lens_strategy, extra = L._RUN_PARTS[r.run]
        assert c.pointing.kind == kind and c.estimator.sphere_method == method
        assert c.estimator.lens_strategy == lens_strategy and c.estimator.extra_methods == extra
        # the moving drone's run of the same motion, mount and seed, apart from camera and estimator
        drone = MovingDroneStudy().config("sphere", motion, {"paper": "active"}.get(kind, kind), "global", c.seed)
        assert c.replace(camera=drone.camera, estimator=drone.estimator, revolutions=2.0) == drone


def test_parameters_are_checked_and_seeds_kept_apart():
    with pytest.raises(ValueError, match="also test seeds"):
        X.ExposureStudy(calibration_seeds=(100, 201))
    with pytest.raises(ValueError, match="exposures_ms"):
        X.ExposureStudy(exposures_ms=(1.0, 40.0))
    with pytest.raises(ValueError, match=r"revolutions must be >= 0\.2 and"):
        X.ExposureStudy(revolutions=0.19)
    with pytest.raises(ValueError, match="replicates"):
        X.ExposureStudy(replicates=1)
    with pytest.raises(ValueError, match="pipeline must be one of"):
        X.config(0, "active (fancy)", 0.001, 200)
    with pytest.raises(ValueError, match="condition must be one of"):
        X.config(6, "active (best)", 0.001, 200)


def _choices(rows):
    return pd.DataFrame(rows, columns=["point", "pipeline", "exposure_s", "error_m"])


def test_a_passive_mounts_pipelines_that_chose_one_exposure_share_its_test_run():
    choices = _choices([(0, "active (paper)", 0.001, 0.01), (0, "active (best)", 0.0167, 0.01),
                        (0, "fixed, circle", 0.001, 0.02), (0, "fixed, cone fit", 0.001, 0.03),
                        (0, "fixed, streak", 0.0167, 0.02), (0, "stabilised, circle", math.nan, math.nan),
                        (0, "stabilised, cone fit", 0.001, 0.02), (0, "stabilised, streak", 0.001, 0.02)])
    index = X.test_index(choices, X.ExposureStudy(**SMALL))
    runs = sorted(set(zip(index["run"], index["exposure_s"])))
    assert runs == [("active (best)", 0.0167), ("active (paper)", 0.001), ("fixed", 0.001), ("fixed", 0.0167),
                    ("stabilised", 0.001)]
    assert len(index) == 5 * 2 and set(index["seed"]) == {200, 201}
    configs = X.test_configs(index, X.ExposureStudy(**SMALL))
    assert [c.camera.exposure_s for c in configs] == list(index["exposure_s"])


class _Result:
    def __init__(self, frames):
        self.frames = frames


def _frames(errors, detected=None, alt=None, circle=None):
    """A run's frames: two acquisition frames then the measured ones (every column family)."""
    n = len(errors)
    detected = [True] * n if detected is None else detected
    alt = errors if alt is None else alt
    circle = errors if circle is None else circle
    return pd.DataFrame({"frame": np.arange(n), "revolution": [0, 0] + [1] * (n - 2), "detected": detected,
                         "abs_error_m": errors, "alt_detected": [True] * n, "alt_abs_error_m": alt,
                         "circle_detected": [True] * n, "circle_abs_error_m": circle})


def _study_of_two_pipelines(active_by_seed, passive_by_seed, best_passive="fixed, streak"):
    """One condition (0) where active (best) and the fixed mount's three pipelines ran; per seed the
    measured errors of active (best) and of each passive pipeline (streak, cone fit, circle)."""
    choices = _choices([(0, "active (best)", 0.001, 0.01), (0, "fixed, streak", 0.0167, 0.01),
                        (0, "fixed, cone fit", 0.0167, 0.01), (0, "fixed, circle", 0.0167, 0.01)])
    study = X.ExposureStudy(calibration_seeds=(100,), replicates=len(active_by_seed), exposures_ms=(1.0, 16.7))
    index = X.test_index(choices, study)
    results = []
    for r in index.itertuples():
        i = r.seed - 200
        if r.run == "active (best)":
            results.append(_Result(_frames([9.0, 9.0] + list(active_by_seed[i]))))
        else:
            streak, cone, circle = passive_by_seed[i]
            results.append(_Result(_frames([9.0, 9.0] + list(streak), alt=[9.0, 9.0] + list(cone),
                                           circle=[9.0, 9.0] + list(circle))))
    best = pd.DataFrame([{"point": 0, "best_active": "active (best)", "best_passive": best_passive}])
    return choices, index, results, best


def test_pairs_read_each_pipeline_from_its_own_columns_on_common_frames():
    active = [(0.002, 0.004)] * 2
    passive = [((0.010, 0.010), (0.020, 0.030), (0.040, 0.060))] * 2
    choices, index, results, _ = _study_of_two_pipelines(active, passive)
    pairs = X.pair_table(choices, index, results)
    assert len(pairs) == 2 * 3 and set(pairs["active"]) == {"active (best)"}
    got = pairs.set_index(["seed", "passive"])
    assert got.loc[(200, "fixed, streak"), "passive_m"] == pytest.approx(0.010)
    assert got.loc[(200, "fixed, cone fit"), "passive_m"] == pytest.approx(0.025)
    assert got.loc[(201, "fixed, circle"), "passive_m"] == pytest.approx(0.050)
    assert pairs["active_m"].to_numpy() == pytest.approx([0.003] * 6) and (pairs["common_rate"] == 1.0).all()


def test_sp_holds_only_against_every_passive_and_names_the_one_that_decides():
    rng = np.random.default_rng(3)
    seeds = 5
    active = [tuple(0.003 + 0.0002 * rng.standard_normal(4)) for _ in range(seeds)]
    far = [(tuple(0.030 + 0.001 * rng.standard_normal(4)), tuple(0.040 + 0.001 * rng.standard_normal(4)),
            tuple(0.050 + 0.001 * rng.standard_normal(4))) for _ in range(seeds)]
    choices, index, results, best = _study_of_two_pipelines(active, far)
    v = X.check_hypotheses(X.pair_table(choices, index, results), best)
    assert len(v) == 24 and v["p_holm"].notna().sum() == 2  # one condition, active (best) only
    sp2 = v[(v["id"] == "SP2′") & (v["condition"] == "hover, 300 lx")].iloc[0]
    bp2 = v[(v["id"] == "BP2′") & (v["condition"] == "hover, 300 lx")].iloc[0]
    assert sp2["verdict"] == stats.HOLDS and sp2["k"] == 3 and bp2["verdict"] == stats.HOLDS
    assert bp2["b"] == "fixed, streak" and bp2["mean_b"] == pytest.approx(np.mean([np.mean(f[0]) for f in far]))
    # the streak localiser as good as the gimbal: SP2' does not hold, named; BP2' against it too
    close = [(tuple(np.array(a) + 0.00001 * rng.standard_normal(4)), f[1], f[2]) for a, f in zip(active, far)]
    choices, index, results, best = _study_of_two_pipelines(active, close)
    v = X.check_hypotheses(X.pair_table(choices, index, results), best)
    sp2 = v[(v["id"] == "SP2′") & (v["condition"] == "hover, 300 lx")].iloc[0]
    assert sp2["verdict"] == stats.DOES_NOT_HOLD and sp2["b"] == "fixed, streak"
    # untested claims: the conditions without runs, and active (paper), which chose nothing here
    untested = v[v["n"] == 0]
    assert len(untested) == 22 and (untested["verdict"] == stats.INCONCLUSIVE).all()
    assert set(v[v["a"] == "active (paper)"]["n"]) == {0}


def test_bp_compares_with_the_best_passive_chosen_on_calibration_not_the_best_on_test():
    rng = np.random.default_rng(5)
    active = [tuple(0.010 + 0.0002 * rng.standard_normal(4)) for _ in range(5)]
    # on the test seeds the circle method beats the gimbal, the streak localiser does not
    passive = [(tuple(0.030 + 0.0005 * rng.standard_normal(4)), tuple(0.040 + 0.0005 * rng.standard_normal(4)),
                tuple(0.002 + 0.0001 * rng.standard_normal(4))) for _ in range(5)]
    choices, index, results, best = _study_of_two_pipelines(active, passive, best_passive="fixed, streak")
    v = X.check_hypotheses(X.pair_table(choices, index, results), best).set_index(["id", "condition"])
    assert v.loc[("BP2′", "hover, 300 lx"), "verdict"] == stats.HOLDS and v.loc[("BP2′", "hover, 300 lx"), "b"] == "fixed, streak"
    assert v.loc[("SP2′", "hover, 300 lx"), "verdict"] == stats.DOES_NOT_HOLD and v.loc[("SP2′", "hover, 300 lx"), "b"] == "fixed, circle"


def test_the_family_is_the_24_verdicts_under_holm():
    rng = np.random.default_rng(9)
    active = [tuple(0.003 + 0.0002 * rng.standard_normal(4)) for _ in range(5)]
    far = [(tuple(0.030 + 0.001 * rng.standard_normal(4)),) * 3 for _ in range(5)]
    choices, index, results, best = _study_of_two_pipelines(active, far)
    v = X.check_hypotheses(X.pair_table(choices, index, results), best)
    again = stats.holm(v.drop(columns=["p_holm", "verdict_holm"]))
    assert list(again["p_holm"].fillna(-1)) == list(v["p_holm"].fillna(-1)) and len(v) == 24
    smallest = v["p_value"].min()
    assert v["p_holm"].min() == pytest.approx(min(1.0, 24 * smallest))  # Holm's first step: all 24 counted


def test_the_command_line_knows_the_study_and_refuses_bad_parameters_before_any_run(tmp_path, capsys, monkeypatch):
    from gimbal_lab import cli, runner
    from gimbal_lab.studies import STUDIES

    assert STUDIES["exposure"] == "gimbal_lab.studies.exposure"
    monkeypatch.setattr(runner, "run", lambda *a, **k: pytest.fail("a run was computed"))
    config = tmp_path / "exposure.toml"
    config.write_text("[exposure]\ncalibration_seeds = [100, 200]\n")
    with pytest.raises(SystemExit) as exc:
        cli.main(["run", "exposure", "--out", str(tmp_path / "out"), "--config", str(config)])
    assert exc.value.code == 2 and "calibration_seeds [200] are also test seeds" in capsys.readouterr().err


def test_maps_refuse_the_inherited_parameters_they_do_not_use():
    # a study parameter that is set and does nothing would mislead: the sensor model sets the
    # noise of the light map and of this study; the payoff map samples frame rate, latency and noise
    from gimbal_lab.studies.payoff import PayoffStudy

    for make, name, value in ((X.ExposureStudy, "noise_std", 4.0), (L.LightStudy, "noise_std", 0.5),
                              (PayoffStudy, "fps", 60.0), (PayoffStudy, "latency_frames", 2),
                              (PayoffStudy, "noise_std", 3.0)):
        with pytest.raises(ValueError, match=rf"^{name} is not used by this study"):
            make(**{name: value})
        assert getattr(make(), name) == getattr(make(**{name: getattr(make(), name)}), name)  # the default is fine
    assert X.ExposureStudy(fps=25.0).fps == 25.0 and L.LightStudy(fps=25.0).fps == 25.0  # used: accepted
