"""The paper's study: its grid, replicate draws, parameters, and claims on hand-built tables."""

import itertools

import numpy as np
import pandas as pd
import pytest

from gimbal_lab import stats
from gimbal_lab.studies import paper

SEEDS = range(10)
DISTS, TRAJS, MODES = paper.DISTORTIONS, paper.TRAJECTORIES, paper.MODES
# alternating ±0.1 mm: a replicate spread that leaves every designed effect far outside its interval
JITTER = np.array([-1, 1, -1, 1, -1, 1, -1, 1, -1, 1]) * 1e-4


def paper_like_errors():
    """Mean errors (m) per cell shaped so that every claim of §4.1 holds with a wide effect."""
    err = {}
    for dist, traj, mode in itertools.product(DISTS, TRAJS, MODES):
        base = 0.020 if dist == "undistorted" else 0.060
        base *= 1.0 if traj == "circular" else 0.8
        gap = (0.030 if traj == "circular" else 0.010) * (1 if dist == "undistorted" else 2)
        err[("sphere", dist, traj, mode)] = base + (gap if mode == "passive" else 0.0)
        if dist == "undistorted":
            err[("aruco", dist, traj, mode)] = 0.005
        else:
            err[("aruco", dist, traj, mode)] = (0.040 if traj == "circular" else 0.025) + (0.010 if mode == "passive" else 0)
    return err


def make_replicates(err, overrides=None, jitter=JITTER):
    """A replicate table: every cell gets its mean error plus the same per-seed jitter."""
    rows = []
    for (target, dist, traj, mode), e in err.items():
        for seed in SEEDS:
            row = dict(target=target, distortion=dist, trajectory=traj, mode=mode,
                       outer_loop="paper" if mode == "active" else "none",
                       method="circle" if target == "sphere" else "aruco-subpix", seed=seed,
                       mean_abs_error_m=e + jitter[seed])
            row.update(mean_abs_err_cam_x_m=0.1 * e, mean_abs_err_cam_y_m=0.1 * e, mean_abs_err_cam_z_m=0.9 * e)
            lateral = 0.006 if mode == "active" else 0.002
            row.update(mean_abs_err_x_m=0.001, mean_abs_err_y_m=lateral + jitter[seed], mean_abs_err_z_m=lateral)
            rows.append(row)
    df = pd.DataFrame(rows)
    for (target, dist, traj, mode, column), value in (overrides or {}).items():
        sel = (df.target == target) & (df.distortion == dist) & (df.trajectory == traj) & (df["mode"] == mode)
        df.loc[sel, column] = value
    return df


def verdicts_of(claims, cid):
    return claims[claims["id"] == cid]["verdict"].tolist()


def test_every_claim_holds_on_paper_like_replicates():
    claims = paper.check_claims(make_replicates(paper_like_errors()))
    assert list(dict.fromkeys(claims["id"])) == ["S1", "S2", "S3", "S4", "S5", "A1", "A2", "A3", "A4", "A5", "A6"]
    assert len(claims) == 27
    assert (claims["verdict"] == stats.HOLDS).all(), claims[claims["verdict"] != stats.HOLDS]
    assert (claims["n"] == 10).all()


@pytest.mark.parametrize(
    "cid, change",
    [
        ("S1", {("sphere", "undistorted", "diagonal", "active", "mean_abs_error_m"): 0.5}),
        ("S2", {("sphere", "distorted", "diagonal", "passive", "mean_abs_error_m"): 0.3}),
        ("S3", {("sphere", "distorted", "circular", "active", "mean_abs_error_m"): 0.001}),
        ("S4", {("sphere", "distorted", "diagonal", "passive", "mean_abs_error_m"): 0.2}),
        ("S5", {("sphere", "undistorted", "circular", "passive", "mean_abs_err_cam_x_m"): 1.0}),
        ("A1", {("aruco", "undistorted", "circular", "passive", "mean_abs_error_m"): 0.045}),
        ("A2", {("aruco", "undistorted", "diagonal", "active", "mean_abs_error_m"): 0.010}),
        ("A3", {("aruco", "distorted", "diagonal", "active", "mean_abs_error_m"): 0.001}),
        ("A4", {("aruco", "distorted", "circular", "active", "mean_abs_error_m"): 0.09}),
        ("A5", {("aruco", "distorted", "diagonal", "active", "mean_abs_error_m"): 0.06}),
        ("A6", {("aruco", "distorted", "diagonal", "active", "mean_abs_err_z_m"): 0.0005}),
    ],
)
def test_each_claim_does_not_hold_when_its_numbers_say_so(cid, change):
    claims = paper.check_claims(make_replicates(paper_like_errors(), change))
    assert stats.DOES_NOT_HOLD in verdicts_of(claims, cid), claims[claims["id"] == cid]


def test_a_noisy_claim_is_inconclusive():
    err = paper_like_errors()
    df = make_replicates(err)
    # S1 distorted/diagonal: active 48 mm vs passive 68 mm, but ±60 mm replicate scatter on active
    sel = (df.target == "sphere") & (df.distortion == "distorted") & (df.trajectory == "diagonal") & (df["mode"] == "active")
    df.loc[sel, "mean_abs_error_m"] = err[("sphere", "distorted", "diagonal", "active")] + 0.06 * np.array(
        [-1, 1] * 5)
    claims = paper.check_claims(df)
    row = claims[(claims.id == "S1") & (claims.condition == "distorted, diagonal")].iloc[0]
    assert row.verdict == stats.INCONCLUSIVE and row.low < 0 < row.high


def test_equivalence_uses_the_twenty_percent_margin():
    err = paper_like_errors()  # ArUco undistorted: 5 mm everywhere
    inside = {("aruco", "undistorted", "circular", "active", "mean_abs_error_m"): 0.005 * 1.1 + JITTER}
    claims = paper.check_claims(make_replicates(err, inside))
    row = claims[(claims.id == "A2") & (claims.condition == "circular")].iloc[0]
    assert row.verdict == stats.HOLDS
    assert row.delta == pytest.approx(0.2 * 0.5 * (0.0055 + 0.005), rel=1e-9)


def test_one_target_checks_its_own_claims():
    df = make_replicates(paper_like_errors())
    assert set(paper.check_claims(df[df.target == "sphere"])["id"]) == {"S1", "S2", "S3", "S4", "S5"}
    assert set(paper.check_claims(df[df.target == "aruco"])["id"]) == {"A2", "A3", "A4", "A5", "A6"}


def test_missing_cell_and_unpaired_seeds_are_clear_errors():
    df = make_replicates(paper_like_errors())
    missing = df[~((df.target == "sphere") & (df.distortion == "distorted") & (df.trajectory == "circular")
                   & (df["mode"] == "active"))]
    with pytest.raises(ValueError, match="no rows for sphere/distorted/circular/active"):
        paper.check_claims(missing)
    shifted = df.copy()
    shifted.loc[shifted.target == "aruco", "seed"] += 1
    with pytest.raises(ValueError, match="pair replicates by seed"):
        paper.check_claims(shifted)


def test_claims_markdown_says_what_active_means_and_why_claims_fail():
    change = {("sphere", "distorted", "circular", "active", "mean_abs_error_m"): 0.001}
    df = make_replicates(paper_like_errors(), change)
    claims = paper.check_claims(df)
    text = paper.claims_markdown(claims, df, paper.PaperStudy())
    assert "Ziegler–Nichols" in text
    s3 = [line for line in text.splitlines() if line.startswith("- **S3**")]
    assert len(s3) == 1 and "the opposite is measured" in s3[0]
    failing = claims[claims.verdict != stats.HOLDS]
    # every claim that does not hold gets its own line of measured reason
    assert len([line for line in text.splitlines() if line.startswith("- **")]) >= len(failing) > 0
    assert f"{(claims.verdict == stats.HOLDS).sum()} holds" in text


def test_grid_is_sixteen_cells_times_replicates_with_shared_draws():
    study = paper.PaperStudy(replicates=3)
    configs = paper.grid(study)
    assert len(configs) == 48 and len({c for c in configs}) == 48
    by_seed = {}
    for c in configs:
        by_seed.setdefault(c.seed, set()).add(c.target.start_phase_s)
        assert c.revolutions == 2 and c.camera.noise_std == 2.0 and c.n_frames == 120
        assert c.pointing.kind == ("paper" if c.pointing.active else "stabilised")
    # every cell of a replicate shares its start phase; replicates differ
    assert all(len(phases) == 1 for phases in by_seed.values())
    phases = [next(iter(p)) for p in by_seed.values()]
    assert len(set(phases)) == 3 and all(0 <= p < 2.0 for p in phases)
    assert paper.replicate_phase_s(5, 2.0) == paper.replicate_phase_s(5, 2.0)


@pytest.mark.parametrize(
    "kwargs, field",
    [(dict(replicates=1), "replicates"), (dict(replicates=True), "replicates"), (dict(replicates="10"), "replicates"),
     (dict(revolutions=1.5), "revolutions"), (dict(revolutions=float("nan")), "revolutions"),
     (dict(first_seed=-1), "first_seed"), (dict(outer_loop="pid"), "outer_loop"), (dict(fps=0), "fps"),
     (dict(latency_frames=10_000), "latency_frames"), (dict(noise_std=-2), "noise_std")],
)
def test_bad_study_parameters_name_the_field(kwargs, field):
    with pytest.raises((ValueError, TypeError), match=field):
        paper.PaperStudy(**kwargs)


def test_study_config_from_toml(tmp_path):
    good = tmp_path / "paper.toml"
    good.write_text("[paper]\nreplicates = 4\nrevolutions = 3.0\n")
    assert paper.PaperStudy.from_toml(good) == paper.PaperStudy(replicates=4, revolutions=3.0)
    bad = tmp_path / "bad.toml"
    bad.write_text("[paper]\nreplicate = 4\n")
    with pytest.raises(ValueError, match="unknown key.*replicate"):
        paper.PaperStudy.from_toml(bad)
    with pytest.raises(FileNotFoundError, match="does not exist"):
        paper.PaperStudy.from_toml(tmp_path / "missing.toml")


def test_the_shipped_study_config_is_the_study_default():
    from pathlib import Path

    shipped = Path(__file__).resolve().parents[1] / "data" / "studies" / "paper.toml"
    assert paper.PaperStudy.from_toml(shipped) == paper.PaperStudy()


def test_write_clips_shows_each_targets_clip_cell(tmp_path):
    """One MP4 per target, of the distorted circular cell's first replicate, passive | active."""
    import cv2

    from gimbal_lab.simulation import simulate
    from gimbal_lab.video import probe_video

    study = paper.PaperStudy(replicates=2, period_s=0.3)  # 2 revolutions of 9 frames
    cell = [c for c in paper.grid(study) if (c.camera.lens_label, c.target.trajectory, c.seed) == (*paper.CLIP_CELL, 0)]
    other = [c for c in paper.grid(study, targets=("sphere",)) if c.seed == 1][:1]  # not a clip's run
    assert len(cell) == 4
    results = [simulate(c) for c in cell + other]
    written = paper.write_clips(tmp_path, results, study)
    assert [p.name for p in written] == ["sphere.mp4", "aruco.mp4"]
    for path in written:
        cap = cv2.VideoCapture(str(path))
        frames, width = int(cap.get(cv2.CAP_PROP_FRAME_COUNT)), int(cap.get(cv2.CAP_PROP_FRAME_WIDTH))
        cap.release()
        assert (frames, width) == (cell[0].n_frames, 2 * cell[0].camera.width + 4)
        info = probe_video(path)  # what a browser plays
        assert (info.codec, info.pixel_format, info.frames) == ("h264", "yuv420p", cell[0].n_frames)
    # a target whose pair is missing gets no clip (e.g. a study run for one target)
    assert paper.write_clips(tmp_path / "none", results[:1], study) == []


def test_report_writes_tables_claims_figures_and_metadata(tmp_path):
    """The whole 16-cell grid, 2 replicates of 2 revolutions of 9 frames, through write_report."""
    import json

    import pandas as pd

    from gimbal_lab.runner import run

    study = paper.PaperStudy(replicates=2, period_s=0.3)
    results = run(paper.grid(study), jobs=1, progress=False)
    written = paper.write_report(tmp_path, results, study)
    names = {p.relative_to(tmp_path).as_posix() for p in written}
    for name in ("summary.csv", "replicates.parquet", "frames.parquet", "verdicts.csv", "claims.md", "study.json",
                 "figures/fig11_sphere_error.png", "figures/fig14_aruco_xyz_active.svg", "figures/claims_forest.png"):
        assert name in names and (tmp_path / name).stat().st_size > 0
    meta = json.loads((tmp_path / "study.json").read_text())
    assert meta["study"] == "paper" and meta["runs"] == 32 and meta["parameters"] == study.to_dict()
    assert len(pd.read_parquet(tmp_path / "frames.parquet")) == 32 * 18
    assert len(pd.read_csv(tmp_path / "verdicts.csv")) == 27
