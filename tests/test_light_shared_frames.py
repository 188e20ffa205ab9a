"""One passive run records three localisers of the same frames (the buying-rule map's passive runs).

On a passive mount the estimator steers nothing, so the circle method, the cone fit and the
blur-aware localiser of one mount, seed and exposure see the same frames. The map records them in
one run: the streak method's own columns, the cone fit beside it (``alt_*``) and the circle method's
family (``circle_*``, ``Estimator(extra_methods=("circle",))``). The oracle here is the runs the
sharing replaces, rendered apart: each column of the shared run must equal, bit for bit, the same
column of the run that records that localiser as its own estimate.
"""

import numpy as np
import pandas as pd
import pytest

from gimbal_lab import runner
from gimbal_lab.config import SPHERE_FAMILY_COLUMNS, Estimator, TrackingConfig
from gimbal_lab.simulation import FRAME_COLUMNS, _COLUMNS, frame_columns, make_renderer, simulate
from gimbal_lab.studies import light as L

#: A point of the map where the target streaks some 10 px at 16.7 ms in front of the sky (so the
#: streak method reads coverage rather than falling back to the cone fit) and the body vibrates.
VALUES = {"light_lux": 1000.0, "rate_rad_s": 1.2, "range_m": 3.0, "diameter_px": 40.0, "vibration_deg": 0.2}
N_FRAMES = 8


def _runs(mount):
    """The shared run of ``mount`` and the two runs it replaces, each of N_FRAMES frames, one renderer."""
    shared = L.point_config(VALUES, f"{mount}, streak", 0.0167, 100)
    shared = shared.with_(revolutions=N_FRAMES / (shared.target.period_s * shared.camera.fps))
    assert shared.n_frames == N_FRAMES
    circle = shared.with_(estimator__sphere_method="circle", estimator__extra_methods=())
    streak = shared.with_(estimator__extra_methods=())
    renderer = make_renderer(shared)
    try:
        return tuple(simulate(c, renderer).frames for c in (shared, circle, streak)) + (shared,)
    finally:
        renderer.close()


def _same(a, b):
    """Bit for bit: the same dtype and the same bytes (NaN with NaN's own bits)."""
    a, b = np.asarray(a), np.asarray(b)
    return a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()


@pytest.mark.parametrize("mount", ["fixed", "stabilised"])
def test_the_shared_run_records_what_the_separate_runs_record(mount):
    shared, circle, streak, config = _runs(mount)
    family = [f"circle_{name}" for name in SPHERE_FAMILY_COLUMNS]
    # a run that does not ask for the family keeps the frame table every study has
    assert list(circle.columns) == _COLUMNS and list(streak.columns) == _COLUMNS
    assert list(shared.columns) == _COLUMNS + family == frame_columns(config)
    # the streak run without the family: every column of the shared run's own table, bit for bit
    for column in _COLUMNS:
        assert _same(shared[column], streak[column]), column
    # the circle-method run: its own estimate is the shared run's circle_* family, bit for bit, and
    # its alt_* (the cone fit) the shared run's alt_*; every column that is no estimate is the same
    own = ["detected", "est_x_m", "est_y_m", "est_z_m", "est_cam_x_m", "est_cam_y_m", "est_cam_z_m",
           "d_est_m", "error_m", "abs_error_m"]
    assert len(own) == len(SPHERE_FAMILY_COLUMNS)
    for name, column in zip(SPHERE_FAMILY_COLUMNS, own):
        assert _same(shared[f"circle_{name}"], circle[column]), name
        assert _same(shared[f"alt_{name}"], circle[f"alt_{name}"]), name
    estimates = set(own) | {f"alt_{n}" for n in SPHERE_FAMILY_COLUMNS}
    for column in _COLUMNS:
        if column not in estimates:
            assert _same(shared[column], circle[column]), column
    # the three localisers differ on these frames: the test compares different numbers
    detected = shared["detected"].to_numpy(bool) & shared["circle_detected"].to_numpy(bool)
    assert detected.sum() >= N_FRAMES - 2
    d = shared.loc[detected, ["d_est_m", "alt_d_est_m", "circle_d_est_m"]].to_numpy()
    assert np.all(np.abs(d[:, 0] - d[:, 1]) > 1e-3) and np.all(np.abs(d[:, 0] - d[:, 2]) > 1e-3)
    # the store takes the shared table for its config, and refuses it for a config without the family
    runner.check_frames(shared, config)
    with pytest.raises(ValueError, match="unknown 'circle_detected'"):
        runner.check_frames(shared, config.with_(estimator__extra_methods=()))
    with pytest.raises(ValueError, match="missing 'circle_detected'"):
        runner.check_frames(streak, config)


def test_the_map_reads_each_passive_pipeline_from_its_family():
    # worked by hand: frames 2-4 are measured; each family has its own detections and errors
    n = 5
    frames = pd.DataFrame({"revolution": [0, 0, 1, 1, 1],
                           "detected": [True] * n, "abs_error_m": [9, 9, 0.001, 0.002, 0.003],
                           "alt_detected": [True, True, False, True, True], "alt_abs_error_m": [9, 9, 7, 0.010, 0.020],
                           "circle_detected": [True, True, True, True, False],
                           "circle_abs_error_m": [9, 9, 0.100, 0.300, 8]})
    e = L.run_errors(frames, "stabilised")
    assert e["stabilised, streak"] == (pytest.approx(0.002), 3)
    assert e["stabilised, cone fit"] == (pytest.approx(0.015), 2)
    assert e["stabilised, circle"] == (pytest.approx(0.200), 2)


def test_extra_methods_are_refused_where_they_would_repeat_a_column_and_left_out_when_empty():
    assert "extra_methods" not in Estimator().to_dict()  # the default: every stored run keeps its key
    assert TrackingConfig().key == TrackingConfig(estimator=Estimator(extra_methods=[])).key
    e = Estimator(sphere_method="streak", extra_methods=["circle"])
    assert e.extra_methods == ("circle",) and e.to_dict()["extra_methods"] == ["circle"]
    assert Estimator.from_dict(e.to_dict()) == e
    assert TrackingConfig(estimator=e).key != TrackingConfig(estimator=Estimator(sphere_method="streak")).key
    assert Estimator(sphere_method="circle", extra_methods=("streak",)).extra_methods == ("streak",)
    for method, extra in (("streak", ("ellipse",)),  # the streak method records the cone fit beside it
                          ("streak", ("streak",)), ("circle", ("ellipse",)), ("ellipse", ("circle",)),
                          ("circle", ("streak", "streak"))):
        with pytest.raises(ValueError, match="estimator.extra_methods"):
            Estimator(sphere_method=method, extra_methods=extra)
    with pytest.raises(ValueError, match="estimator.extra_methods"):
        Estimator(extra_methods=("hough",))
    with pytest.raises(TypeError, match="estimator.extra_methods"):
        Estimator(sphere_method="streak", extra_methods="circle")
    marker = TrackingConfig().with_(target__kind="aruco", estimator__extra_methods=("streak",))
    with pytest.raises(ValueError, match="sphere localisers"):
        marker.estimator.build(marker.camera, marker.target)
    assert "<method>_*" in FRAME_COLUMNS
    assert frame_columns(marker) == _COLUMNS + [f"streak_{name}" for name in SPHERE_FAMILY_COLUMNS]
