"""Plot helpers whose behaviour goes beyond drawing: what the interactive explorer shows."""

import itertools

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt
import pandas as pd
import pytest

from gimbal_lab.camera import BrownConrady, Intrinsics
from gimbal_lab.plotting import camera as camera_plots


@pytest.fixture(autouse=True)
def live_widgets(monkeypatch):
    """These tests drive the widgets themselves (the suite's conftest switches them off for notebooks)."""
    monkeypatch.setenv("GIMBAL_LAB_WIDGETS", "1")


def test_widgets_switched_off_draw_once_with_the_initial_values(monkeypatch):
    from gimbal_lab.plotting import interactive

    ipywidgets = pytest.importorskip("ipywidgets")
    calls = []
    monkeypatch.setenv("GIMBAL_LAB_WIDGETS", "0")
    assert interactive(lambda a, b: calls.append((a, b)), a=ipywidgets.IntSlider(value=3), b=2.5) is None
    assert calls == [(3, 2.5)]
    monkeypatch.setenv("GIMBAL_LAB_WIDGETS", "1")
    assert isinstance(interactive(lambda a: calls.append(a), a=ipywidgets.IntSlider(value=4)), ipywidgets.interactive)


def test_distortion_explorer_starts_at_the_given_lens_and_keeps_its_other_coefficients(monkeypatch):
    pytest.importorskip("ipywidgets")
    drawn = []
    monkeypatch.setattr(camera_plots, "plot_distorted_grid", lambda intrinsics, lens, ax: drawn.append(lens))
    monkeypatch.setattr(camera_plots, "plot_displacement_field", lambda intrinsics, lens, ax: None)
    lens = BrownConrady(k1=-0.25, k2=0.12, p1=-0.00028, p2=-0.00005, k3=0.01)
    widget = camera_plots.distortion_explorer(Intrinsics.default(), lens)
    assert widget.kwargs == {"k1": lens.k1, "k2": lens.k2}
    widget.children[0].value = 0.1  # move the k1 slider
    # the first picture is the lens itself; moving a slider changes k1 only
    assert drawn[0] == lens
    assert drawn[-1] == BrownConrady(k1=0.1, k2=0.12, p1=-0.00028, p2=-0.00005, k3=0.01)
    with pytest.raises(TypeError, match="BrownConrady"):
        camera_plots.distortion_explorer(Intrinsics.default(), "barrel")
    with pytest.raises(ValueError, match="k_range"):
        camera_plots.distortion_explorer(Intrinsics.default(), lens, k_range=0)


@pytest.fixture(scope="module")
def cell_runs():
    from gimbal_lab.simulation import TrackingConfig, simulate

    base = TrackingConfig().with_(camera__lens="default", camera__width=320, camera__height=240,
                                  target__start_phase_s=0.3, revolutions=0.5)
    return [simulate(base.with_(pointing__kind=kind, seed=s)) for s in (0, 1) for kind in ("stabilised", "paper")]


def test_run_frame_shows_both_cameras_at_the_instant_and_the_error_trace(cell_runs):
    import numpy as np

    from gimbal_lab.plotting import study
    from gimbal_lab.show import annotate, replay

    passive, active = cell_runs[:2]
    fig = study.plot_run_frame(passive, active, 7)
    images = [ax.get_images()[0].get_array() for ax in fig.axes[:2]]
    for result, shown in zip((passive, active), images):
        row, image = list(replay(result))[7]
        past = result.frames.iloc[:8]
        want = annotate(image, row, result.config, zip(past["true_u_px"], past["true_v_px"]), title=result.config.pointing.mode.upper())
        assert np.array_equal(np.asarray(shown), want)
    trace = fig.axes[2]
    marker = [line for line in trace.get_lines() if line.get_linestyle() == "--"]
    assert len(marker) == 1 and marker[0].get_xdata()[0] == passive.frames["t_mid_s"].iloc[7]
    np.testing.assert_allclose(trace.get_lines()[1].get_ydata(), 1000 * active.frames["abs_error_m"])
    assert "frame 7" in fig.get_suptitle() and "revolution 1 of 1" in fig.get_suptitle()
    with pytest.raises(ValueError, match=r"frame must be an integer in \[0, 29\]"):
        study.plot_run_frame(passive, active, 30)


def test_run_explorer_offers_every_paired_cell_and_redraws_on_change(cell_runs):
    pytest.importorskip("ipywidgets")
    from gimbal_lab.plotting import study

    widget = study.run_explorer(cell_runs + cell_runs[:1], frame=3)  # a duplicate pair entry is harmless
    cell, replicate, frame = widget.kwargs_widgets
    assert list(cell.options) == ["distorted/circular"] and list(replicate.options) == [0, 1]
    assert widget.result.startswith("sphere, distorted, circular, replicate 0: frame 3 ")
    frame.value = 12
    assert "frame 12 " in widget.result
    replicate.value = 1
    assert widget.result.startswith("sphere, distorted, circular, replicate 1: frame 12 ")
    with pytest.raises(ValueError, match="no cell with both a passive and an active run"):
        study.run_explorer(cell_runs[:1])


def test_error_bar_whiskers_are_the_replicate_interval_and_never_below_zero():
    import numpy as np
    import pandas as pd

    from gimbal_lab.plotting import study

    rows = []
    for d in ("undistorted", "distorted"):
        for t in ("circular", "diagonal"):
            for mode, mean, low, high in (("passive", 0.070, 0.068, 0.072), ("active", 0.004, -0.001, 0.009)):
                rows.append(dict(target="sphere", distortion=d, trajectory=t, mode=mode, method="circle",
                                 mean_abs_error_m=mean, ci_low_m=low, ci_high_m=high))
    ax = study.plot_error_bars(pd.DataFrame(rows), "sphere")
    bars = [c for c in ax.containers if hasattr(c, "errorbar")]
    passive, active = bars
    for container, low, high in ((passive, 68.0, 72.0), (active, 0.0, 9.0)):  # mm; active's −1 mm drawn at 0
        segments = container.errorbar.lines[2][0].get_segments()
        assert len(segments) == 4
        for seg in segments:
            np.testing.assert_allclose(sorted(seg[:, 1]), [low, high], atol=1e-9)


def _moving_summary():
    import itertools

    import numpy as np
    import pandas as pd

    rows = []
    for i, (target, motion, mount, shutter) in enumerate(itertools.product(
            ("sphere", "aruco"), ("hover", "flight"), ("fixed", "stabilised", "active"), ("global", "rolling"))):
        error = np.nan if (target, motion) == ("aruco", "hover") else 0.001 * (i + 1)
        rows.append(dict(target=target, motion=motion, mount=mount, shutter=shutter, common_abs_error_m=error,
                         ci_low_m=error - 1e-4, ci_high_m=error + 1e-4, detection_rate=0.5,
                         mean_streak_px=float(i), streak_ci_low_px=i - 0.5, streak_ci_high_px=i + 0.5))
    return pd.DataFrame(rows)


def test_mount_bars_draw_the_summary_values_in_mm_and_mark_missing_cells():
    import numpy as np

    from gimbal_lab.plotting import study

    summary = _moving_summary()
    from matplotlib.container import BarContainer

    fig = study.plot_mount_bars(summary)
    axes = np.array(fig.axes).reshape(3, 2)
    bars_of = lambda ax: [c for c in ax.containers if isinstance(c, BarContainer)]  # noqa: E731
    for col, target in enumerate(("sphere", "aruco")):
        df = summary[summary.target == target]
        for mount_index, mount in enumerate(("fixed", "stabilised", "active")):
            bars = bars_of(axes[0, col])[mount_index]
            expected = [1000 * df[(df.motion == m) & (df.shutter == s) & (df["mount"] == mount)].common_abs_error_m.iloc[0]
                        for m in ("hover", "flight") for s in ("global", "rolling")]
            np.testing.assert_allclose([b.get_height() for b in bars], np.nan_to_num(expected), atol=1e-12)
            streaks = [b.get_height() for b in bars_of(axes[2, col])[mount_index]]
            assert streaks == [float(x) for x in df[df["mount"] == mount].mean_streak_px]
    missing = [line for line in axes[0, 1].lines if line.get_marker() == "x"]
    assert sum(len(line.get_xdata()) for line in missing) == 6  # aruco hover: 3 mounts × 2 shutters
    assert not [line for line in axes[0, 0].lines if line.get_marker() == "x"]


def test_forest_prints_each_rows_unit_and_says_when_there_is_no_interval():
    import math

    import pandas as pd

    from gimbal_lab.plotting import study

    verdicts = pd.DataFrame([
        dict(id="H1", condition="c1", a="a", b="b", kind="less", verdict="holds", difference=-0.020, low=-0.025,
             high=-0.015, delta=0.001, n=10, unit="m"),
        dict(id="H3", condition="c2", a="a", b="b", kind="less", verdict="does not hold", difference=2.0, low=1.0,
             high=3.0, delta=1.0, n=10, unit="px"),
        dict(id="H4", condition="c3", a="a", b="b", kind="less", verdict="inconclusive", difference=math.nan,
             low=math.nan, high=math.nan, delta=0.001, n=0, unit="m"),
    ])
    ax = study.plot_forest(verdicts)
    texts = [t.get_text() for t in ax.texts]
    assert texts == ["-20.0 [-25.0, -15.0] mm", "+2.0 [+1.0, +3.0] px", "no interval: 0 complete pair(s)"]


def _lens_summary():
    """A two-lens, two-target summary in the shape of lens_sweep.summary_table."""
    rows = []
    for target, base in (("sphere", 2.0), ("aruco", 9.0)):
        for lens, family, strategies in (("pinhole", "brown-conrady", ("ignore",)),
                                         ("fisheye 120°", "fisheye", ("ignore", "undistort", "rectify"))):
            for strategy in strategies:
                for mode, extra in (("passive", 0.0), ("active", 0.4)):
                    rows.append(dict(target=target, lens=lens, family=family, strategy=strategy, mode=mode,
                                     mean_abs_error_m=0.010 if mode == "active" else 0.200, ci_low_m=0.008,
                                     ci_high_m=0.012, detection_rate_pct=100.0 if strategy != "rectify" else 30.0,
                                     estimate_ms=base + extra + (1.0 if strategy == "rectify" else 0.0),
                                     render_ms=5.0 if lens == "pinhole" else 14.0))
    return pd.DataFrame(rows)


def test_lens_costs_draw_each_targets_strategies_as_the_mean_of_the_modes():
    from gimbal_lab.plotting.study import plot_lens_costs

    fig = plot_lens_costs(_lens_summary())
    sphere_ax = fig.axes[0]
    heights = sorted(round(p.get_height(), 6) for p in sphere_ax.patches if p.get_height() > 0)
    # sphere: pinhole ignore 2.2; fisheye ignore 2.2, undistort 2.2, rectify 3.2 (means of 2.0 and 2.4)
    assert heights == [2.2, 2.2, 2.2, 3.2]
    assert "sphere" in sphere_ax.get_title() and "ArUco" in fig.axes[1].get_title()
    render = sorted(round(p.get_height(), 6) for p in fig.axes[2].patches)
    assert render == [5.0, 5.0, 14.0, 14.0]
    plt.close(fig)


def test_lens_sweep_plots_one_line_per_strategy_and_rejects_unknown_values():
    from gimbal_lab.plotting.study import plot_lens_sweep

    fig = plot_lens_sweep(_lens_summary(), "detection_rate_pct")
    labels = fig.axes[0].get_legend_handles_labels()[1] + fig.axes[1].get_legend_handles_labels()[1]
    assert {"ignore", "undistort", "rectify"} <= set(labels)
    plt.close(fig)
    with pytest.raises(ValueError, match="value must be one of"):
        plot_lens_sweep(_lens_summary(), "speed")


def test_lens_error_cost_puts_each_pipeline_at_its_cpu_cost_and_its_methods_error():
    from gimbal_lab.plotting.study import plot_lens_error_cost

    summary = _lens_summary().assign(cone="field", alt_abs_error_m=0.004)
    # an in-limit cone's row must not be drawn
    summary = pd.concat([summary, summary.iloc[[0]].assign(cone="in-limit", mean_abs_error_m=9.0)], ignore_index=True)
    rows = []
    for r in summary[summary["cone"] == "field"].itertuples():
        for method in (("circle", "exact") if r.target == "sphere" else ("PnP",)):
            cpu = {"ignore": 1.0, "undistort": 1.5, "rectify": 3.0}[r.strategy] + (0.1 if method == "exact" else 0.0)
            rows.append(dict(target=r.target, lens=r.lens, mode=r.mode, strategy=r.strategy, method=method,
                             replicates=3, cpu_ms=cpu, cpu_ci_low_ms=cpu - 0.05, cpu_ci_high_ms=cpu + 0.05))
    fig = plot_lens_error_cost(summary, pd.DataFrame(rows))
    sphere_passive = fig.axes[0]
    points = sorted((round(float(x), 6), round(float(y), 6)) for line in sphere_passive.lines
                    if line.get_marker() in ("o", "s", "D") for x, y in zip(line.get_xdata(), line.get_ydata()))
    # sphere, passive: 4 cells (pinhole ignore, fisheye ×3) × 2 methods; circle at 200 mm, exact at 4 mm
    assert points == sorted([(1.0, 200.0), (1.1, 4.0), (1.0, 200.0), (1.1, 4.0), (1.5, 200.0), (1.6, 4.0),
                             (3.0, 200.0), (3.1, 4.0)])
    assert "sphere" in sphere_passive.get_title() and "passive" in sphere_passive.get_title()
    plt.close(fig)
    with pytest.raises(ValueError, match="must hold rows"):
        plot_lens_error_cost(summary, pd.DataFrame())


def test_lens_h2_limits_draws_each_cones_advantage_and_demand():
    from gimbal_lab.plotting.study import plot_lens_h2_limits

    rows = []
    for target, lens, cone, seed in itertools.product(("sphere",), ("fisheye 120°", "fisheye 185°"),
                                                      ("field", "in-limit"), range(3)):
        gap = {"field": 0.050, "in-limit": 0.200}[cone] * (2 if lens == "fisheye 185°" else 1)
        for mode in ("passive", "active"):
            rows.append(dict(target=target, lens=lens, cone=cone, seed=seed, strategy="ignore", mode=mode,
                             mean_abs_error_m=0.010 + (gap if mode == "passive" else 0.0) + 0.001 * seed))
    demand = pd.DataFrame([dict(lens=lens, cone=cone, peak_yaw_rate_rad_s=rate, rate_limit_rad_s=3.0,
                                stop_pct_sphere=stop)
                           for lens, cone, rate, stop in (("fisheye 120°", "field", 2.8, 10.0),
                                                          ("fisheye 120°", "in-limit", 2.6, 0.0),
                                                          ("fisheye 185°", "field", 6.7, 60.0),
                                                          ("fisheye 185°", "in-limit", 2.6, 0.0))])
    fig = plot_lens_h2_limits(pd.DataFrame(rows), demand)
    advantage = fig.axes[0]
    means = {line.get_color(): [round(float(y), 6) for y in line.get_ydata()] for line in advantage.lines
             if line.get_marker() == "o"}
    # passive − active in mm, per fisheye: field 50, 100; in-limit 200, 400 (the seeds' offsets cancel)
    assert sorted(means.values()) == [[50.0, 100.0], [200.0, 400.0]]
    bars = sorted(round(p.get_height(), 6) for p in fig.axes[1].patches)
    assert bars == [2.6, 2.6, 2.8, 6.7]
    plt.close(fig)


def test_saved_figure_paths_show_in_a_notebook_as_plain_paths(tmp_path):
    """A notebook cell ending in save_figure shows the path(s) written, one per line, as IPython's
    display prints them (not ``PosixPath('...')`` or a list of them); they are still Paths."""
    from pathlib import Path

    from IPython.lib.pretty import pretty

    from gimbal_lab.plotting import save_figure

    fig = plt.figure()
    one = save_figure(fig, "f", tmp_path)
    both = save_figure(fig, "g", tmp_path, formats=("png", "svg"))
    plt.close(fig)
    assert pretty(one) == str(tmp_path / "f.png") and repr(one) == str(tmp_path / "f.png")
    assert pretty(both) == f"{tmp_path / 'g.png'}\n{tmp_path / 'g.svg'}"
    assert one == tmp_path / "f.png" and isinstance(one, Path) and one.stat().st_size > 0
    assert both == [tmp_path / "g.png", tmp_path / "g.svg"] and all(isinstance(p, Path) for p in both)


def test_payoff_map_draws_the_break_even_where_the_surface_changes_sign_and_points_in_mm():
    import numpy as np

    from gimbal_lab.plotting import payoff as pp

    points = pd.DataFrame({"a": [0.2, 0.8], "b": [0.5, 0.5], "class": ["pays off", "does not"],
                           "delta_best_m": [-0.002, 0.003], "delta_best_low_m": [-0.004, 0.001],
                           "delta_best_high_m": [0.0, 0.005]})
    x = y = np.linspace(0.0, 1.0, 21)
    X, _ = np.meshgrid(x, y)
    ax = pp.plot_payoff_map(points, "a", "b", x, y, 0.01 * (X - 0.4))  # zero on the line a = 0.4
    contour = [c for c in ax.collections if type(c).__name__ in ("QuadContourSet", "ContourSet")
               or hasattr(c, "get_paths") and "Contour" in type(c).__name__]
    assert contour, "no break-even drawn"
    vertices = np.vstack([p.vertices for c in contour for p in c.get_paths() if len(p.vertices)])
    assert vertices[:, 0] == pytest.approx(np.full(len(vertices), 0.4), abs=1e-9)
    flat = pp.plot_payoff_map(points, "a", "b", x, y, 0.01 + 0.0 * X)  # one sign: no boundary
    assert not [c for c in flat.collections if "Contour" in type(c).__name__]
    fig = pp.plot_delta_vs_factors(points, [{"name": "a", "label": "a", "low": 0.0, "high": 1.0}],
                                   columns=(("delta_best", "Δ best"),))
    offsets = fig.axes[0].collections[-1].get_offsets()
    assert np.asarray(offsets)[:, 1] == pytest.approx([-2.0, 3.0])  # mm
    plt.close("all")


@pytest.mark.parametrize("u, v, corner", [(50.0, 40.0, (34, 24)), (0.0, 0.0, None), (99.6, 79.4, None)])
def test_crop_around_the_target_is_the_image_around_it_black_beyond_its_edges(u, v, corner):
    """The moving-drone figure's enlarged crop: pixel (r, c) of the crop is image pixel
    (round(v) − zoom + r, round(u) − zoom + c) where that exists, black elsewhere."""
    import numpy as np

    from gimbal_lab.plotting.study import crop_around

    image = np.random.default_rng(0).integers(1, 256, (80, 100, 3), dtype=np.uint8)  # never black
    crop = crop_around(image, u, v, 16)
    assert crop.shape == (32, 32, 3)
    rows, cols = np.mgrid[0:32, 0:32]
    r, c = int(round(v)) - 16 + rows, int(round(u)) - 16 + cols
    inside = (0 <= r) & (r < 80) & (0 <= c) & (c < 100)
    assert np.array_equal(crop[inside], image[r[inside], c[inside]])
    assert not crop[~inside].any()
    if corner is not None:  # wholly inside: the plain slice
        assert np.array_equal(crop, image[corner[1]:corner[1] + 32, corner[0]:corner[0] + 32])


@pytest.mark.parametrize("u, v", [(-0.6, 40.0), (100.6, 40.0), (50.0, -3.0), (50.0, 81.0), (float("nan"), 1.0),
                                  (1.0, float("inf"))])
def test_crop_around_a_target_outside_the_frame_is_none(u, v):
    """A target whose centre is outside the frame (or not projected) has no crop, rather than an
    empty or wrapped-around slice (a flying drone's mount can lose the target at the instant shown)."""
    import numpy as np

    from gimbal_lab.plotting.study import crop_around

    assert crop_around(np.zeros((80, 100, 3), np.uint8), u, v, 16) is None
