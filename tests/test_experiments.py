"""check_claims computes verdicts from the numbers it is given; the grid is the paper's."""

import itertools

import pandas as pd
import pytest

from gimbal_lab.experiments import EQUIVALENCE_MARGIN, check_claims, paper_grid

DISTS = ("undistorted", "distorted")
TRAJS = ("circular", "diagonal")
MODES = ("passive", "active")


def paper_like_errors():
    """Mean errors (m) shaped so that every claim of §4.1 holds."""
    err = {}
    for dist, traj, mode in itertools.product(DISTS, TRAJS, MODES):
        base = 0.020 if dist == "undistorted" else 0.060
        base *= 1.0 if traj == "circular" else 0.8
        gap = (0.010 if traj == "circular" else 0.004) * (1 if dist == "undistorted" else 2)
        err[("sphere", dist, traj, mode)] = base + (gap if mode == "passive" else 0.0)
        if dist == "undistorted":
            err[("aruco", dist, traj, mode)] = 0.005
        else:
            err[("aruco", dist, traj, mode)] = (0.030 if traj == "circular" else 0.020) + (0.005 if mode == "passive" else 0)
    return err


def make_summary(err, overrides=None):
    rows = []
    for (target, dist, traj, mode), e in err.items():
        row = dict(target=target, distortion=dist, trajectory=traj, mode=mode, mean_error_m=e)
        # camera-frame errors: depth dominates; world x/y: active larger on the distorted diagonal
        row.update(mean_abs_err_cam_x_m=0.1 * e, mean_abs_err_cam_y_m=0.1 * e, mean_abs_err_cam_z_m=0.9 * e)
        lateral = 0.004 if mode == "active" else 0.002
        row.update(mean_abs_err_x_m=0.001, mean_abs_err_y_m=lateral, mean_abs_err_z_m=lateral)
        rows.append(row)
    df = pd.DataFrame(rows)
    for (target, dist, traj, mode, column), value in (overrides or {}).items():
        sel = (df.target == target) & (df.distortion == dist) & (df.trajectory == traj) & (df["mode"] == mode)
        df.loc[sel, column] = value
    return df


def verdicts(claims, cid):
    return claims[claims["id"] == cid]["holds"].tolist()


def test_all_claims_hold_on_paper_like_numbers():
    claims = check_claims(make_summary(paper_like_errors()))
    assert set(claims["id"]) == {"S1", "S2", "S3", "S4", "S5", "A1", "A2", "A3", "A4", "A5", "A6"}
    assert claims["holds"].all(), claims[~claims["holds"]]


@pytest.mark.parametrize(
    "cid, change",
    [
        ("S1", {("sphere", "undistorted", "diagonal", "active", "mean_error_m"): 0.5}),
        ("S2", {("sphere", "distorted", "diagonal", "passive", "mean_error_m"): 0.3}),
        ("S3", {("sphere", "distorted", "circular", "active", "mean_error_m"): 0.001}),
        ("S4", {("sphere", "distorted", "diagonal", "passive", "mean_error_m"): 0.2}),
        ("S5", {("sphere", "undistorted", "circular", "passive", "mean_abs_err_cam_x_m"): 1.0}),
        ("A1", {("aruco", "undistorted", "circular", "passive", "mean_error_m"): 0.025}),
        ("A2", {("aruco", "undistorted", "diagonal", "active", "mean_error_m"): 0.005 * (1 + 2 * EQUIVALENCE_MARGIN)}),
        ("A3", {("aruco", "distorted", "diagonal", "active", "mean_error_m"): 0.001}),
        ("A4", {("aruco", "distorted", "circular", "active", "mean_error_m"): 0.05}),
        ("A5", {("aruco", "distorted", "diagonal", "active", "mean_error_m"): 0.04}),
        ("A6", {("aruco", "distorted", "diagonal", "active", "mean_abs_err_z_m"): 0.001}),
    ],
)
def test_each_claim_fails_when_its_numbers_say_so(cid, change):
    claims = check_claims(make_summary(paper_like_errors(), change))
    assert not all(verdicts(claims, cid)), f"{cid} should fail for {change}"


def test_equivalence_margin_boundary():
    err = paper_like_errors()
    inside = {("aruco", "undistorted", "circular", "active", "mean_error_m"): 0.005 * 1.1}
    assert all(verdicts(check_claims(make_summary(err, inside)), "A2"))


def test_one_target_checks_its_own_claims():
    df = make_summary(paper_like_errors())
    sphere = check_claims(df[df.target == "sphere"])
    aruco = check_claims(df[df.target == "aruco"])
    assert set(sphere["id"]) == {"S1", "S2", "S3", "S4", "S5"}
    assert set(aruco["id"]) == {"A2", "A3", "A4", "A5", "A6"}  # A1 compares with the sphere runs


def test_missing_run_is_a_clear_error():
    df = make_summary(paper_like_errors())
    with pytest.raises(ValueError, match="exactly one run"):
        check_claims(df.iloc[1:])


def test_paper_grid_is_sixteen_distinct_runs():
    grid = paper_grid()
    assert len(grid) == 16 and len({c.key for c in grid}) == 16
    assert {c.label for c in grid} == {
        f"{t}/{d}/{tr}/{m}" for t in ("sphere", "aruco") for d in DISTS for tr in TRAJS for m in MODES
    }
    assert all(c.revolutions == 10 and c.period_s == 2.0 and c.fps == 30 for c in grid)
    assert all(c.n_frames == 600 for c in grid)
