"""Plot helpers whose behaviour goes beyond drawing: what the interactive explorer shows."""

import matplotlib

matplotlib.use("Agg")

import pytest

from gimbal_lab.camera import BrownConrady, Intrinsics
from gimbal_lab.plotting import camera as camera_plots


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
