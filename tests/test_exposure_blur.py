"""No exposure without its blur (docs/design.md, "Exposure and blur").

Two checks. Every run of every built-in study (at full size) and of every shipped scenario that
exposes also integrates its exposure: none renders one sharp instant unless it says
``blur="none"``, and none does. And the frame table's ``streak_px`` describes the frame as
rendered: the streak measured in the image from second moments of the target's light, against
the sharp frame of the same instant, agrees with the table.

Oracle of the second check (a hand derivation): a blurred frame is the time average of the sharp
target moved along its path, in linear light. For a straight, uniform streak of length L the
average's covariance along the streak is the sharp target's plus L²/12 (a uniform shift on
[−L/2, L/2] added to an independent position), and across it is unchanged; so
L = √(12·(λ_blur − λ_sharp)) with λ the variances of the red excess along the added direction.
The payoff map's cone is nearly straight over 16 ms (2.9° of a 2 s revolution); its lens bends
the path slightly; the fast blur warps one render and sub-frames sample the streak 1 px apart.
Bound: |L_image − L_table| <= 0.6 px + 6 % of L (1.1 px at the 8.5 px tested); measured within
0.85 px (fast) and 0.71 px (sub-frames). A frame without its blur measures 0.
"""

import math

import cv2
import numpy as np
import pytest

from gimbal_lab.config import Camera, TrackingConfig
from gimbal_lab.scene import _DECODE_LUT
from gimbal_lab.simulation import make_renderer, simulate
from gimbal_lab.studies import STUDIES, load
from gimbal_lab.studies import payoff
from gimbal_lab.studies.scenario import Scenario, grid as scenario_grid, shipped_scenarios


def _study_configs(name):
    module = load(name)
    return getattr(module, "all_configs", module.grid)(module.Study())


def _exposes_without_blur(config: TrackingConfig) -> bool:
    camera = config.camera
    if camera.exposure_s <= 0:
        return False
    return camera.blur_method(occluded=bool(config.target.occluders)) not in ("fast", "subframes")


@pytest.mark.parametrize("name", sorted(STUDIES))
def test_no_run_of_a_built_in_study_exposes_without_blurring(name):
    """Every run the study makes at full size; the payoff map's 960 exposures included."""
    configs = _study_configs(name)
    assert configs
    bad = [c for c in configs if _exposes_without_blur(c)]
    assert not bad, f"{name}: {len(bad)} of {len(configs)} runs expose without blurring, e.g. {bad[0].camera}"


def test_no_run_of_a_shipped_scenario_exposes_without_blurring():
    scenarios = shipped_scenarios()
    assert len(scenarios) >= 3
    for path, _ in scenarios:
        configs = scenario_grid(Scenario.from_toml(path))
        bad = [c for c in configs if _exposes_without_blur(c)]
        assert not bad, f"{path.name}: {len(bad)} runs expose without blurring"


def test_an_exposure_without_its_blur_is_refused_or_named():
    """The two ways the payoff map once rendered a sharp frame at an exposure: sub-frames with one
    render is refused; blur "none" is accepted, says so (blur_method) and records no streak."""
    with pytest.raises(ValueError, match="camera.n_subframes must be >= 2"):
        Camera(exposure_s=0.016, blur="subframes", n_subframes=1)
    camera = Camera(exposure_s=0.016, blur="none")
    assert camera.blur_method() == "none"
    assert Camera(exposure_s=0.016).blur_method() == "fast"
    assert Camera(exposure_s=0.016).blur_method(occluded=True) == "subframes"
    assert Camera().blur_method() == "sharp"


def _red_excess(image_rgb: np.ndarray) -> np.ndarray:
    """Red minus green in linear light: a linear function of the light, so a blurred frame's is the
    time average of the sharp frames'."""
    linear = cv2.LUT(image_rgb, _DECODE_LUT).astype(np.float64)
    return linear[..., 0] - linear[..., 1]


def _covariance(weight: np.ndarray) -> np.ndarray:
    v, u = np.indices(weight.shape, dtype=np.float64)
    w = weight / weight.sum()
    mean_u, mean_v = np.sum(w * u), np.sum(w * v)
    du, dv = u - mean_u, v - mean_v
    return np.array([[np.sum(w * du * du), np.sum(w * du * dv)], [np.sum(w * du * dv), np.sum(w * dv * dv)]])


def _measured_streak_px(blurred: np.ndarray, sharp: np.ndarray, background: np.ndarray, centre_px, half_px) -> float:
    """The streak the blur adds, from the target's light (the frame less the empty background) in
    a window about the target's true centre."""
    u, v = (int(round(c)) for c in centre_px)
    h = int(math.ceil(half_px))
    window = np.s_[max(v - h, 0):v + h + 1, max(u - h, 0):u + h + 1]
    empty = _red_excess(background)[window]
    extra = _covariance(_red_excess(blurred)[window] - empty) - _covariance(_red_excess(sharp)[window] - empty)
    return math.sqrt(max(12.0 * np.linalg.eigvalsh(extra)[-1], 0.0))


def _frames(config: TrackingConfig, monkeypatch) -> tuple[list[np.ndarray], "object"]:
    """The frames a run renders (before noise) and its frame table."""
    images = []
    original = Camera.add_noise

    def keep(self, image, rng):
        images.append(image.copy())
        return original(self, image, rng)

    monkeypatch.setattr(Camera, "add_noise", keep)
    renderer = make_renderer(config)
    try:
        frames = simulate(config, renderer=renderer).frames
    finally:
        renderer.close()
    monkeypatch.setattr(Camera, "add_noise", original)
    return images, frames


@pytest.mark.parametrize("blur", ["auto", "subframes"])
def test_the_frame_tables_streak_is_the_streak_in_the_image(blur, monkeypatch):
    """The payoff map's point with the longest exposure, best passive camera (the target streaks
    across a still frame), noise off: the table's streak against the image's, frame by frame."""
    table = payoff.design()
    row = table.loc[table["exposure_ms"].idxmax()]
    base = payoff.point_config(row, "best passive", seed=0)
    camera = base.camera.replace(noise_std=0.0, blur=blur)
    blurred_cfg = base.replace(camera=camera, revolutions=0.25)
    sharp_cfg = base.replace(camera=camera.replace(blur="none"), revolutions=0.25)
    blurred, f_blur = _frames(blurred_cfg, monkeypatch)
    sharp, f_sharp = _frames(sharp_cfg, monkeypatch)
    assert (f_sharp["streak_px"] == 0).all()  # blur "none": the frames record no streak
    streaks = f_blur["streak_px"].to_numpy()
    assert streaks.min() > 3.0  # the point streaks: the check can see a missing blur
    # the still camera's empty background: each pixel's median over the run's sharp frames (the
    # target covers a pixel in at most two of them)
    background = np.median(np.stack(sharp), axis=0).astype(np.uint8)
    half_px = row["diameter_px"] + streaks.max() + 8
    measured = np.array([_measured_streak_px(b, s, background, (u, v), half_px) for b, s, u, v in
                         zip(blurred, sharp, f_blur["true_u_px"], f_blur["true_v_px"])])
    np.testing.assert_allclose(measured, streaks, rtol=0.06, atol=0.6)


def test_a_scenario_that_asks_for_sharp_exposures_says_so_in_its_claims(tmp_path):
    """blur = "none" is allowed in a scenario file, and its report's rig sentence says the frames
    are rendered sharp although the camera exposes; a blurred one says how it blurs."""
    import pandas as pd

    text = ('description = "a sharp rig"\n[run]\nreplicates = 2\n[camera]\nexposure_s = 0.01\nblur = "{blur}"\n'
            '[sweep]\npointing = ["stabilised", "paper"]\n'
            '[compare.H1]\na = "paper"\nb = "stabilised"\nstatement = "the loop beats the passive camera"\n')
    said = {}
    for blur in ("none", "auto"):
        path = tmp_path / f"{blur}.toml"
        path.write_text(text.format(blur=blur))
        scenario = Scenario.from_toml(path)
        from gimbal_lab.studies.scenario import hypotheses_markdown

        said[blur] = hypotheses_markdown(pd.DataFrame(), pd.DataFrame(), scenario)
    assert "exposure 10.0 ms rendered SHARP (blur = \"none\"" in said["none"]
    assert "exposure 10.0 ms, blurred (fast)" in said["auto"] and "SHARP" not in said["auto"]
