"""Plot helpers whose behaviour goes beyond drawing: what the interactive explorer shows."""

import matplotlib

matplotlib.use("Agg")

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

    base = dict(target="sphere", distortion="default", revolutions=0.5, width=320, height=240, start_phase_s=0.3)
    return [simulate(TrackingConfig(mode=m, seed=s, **base)) for s in (0, 1) for m in ("passive", "active")]


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
        want = annotate(image, row, result.config, zip(past["true_u_px"], past["true_v_px"]), title=result.config.mode.upper())
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
