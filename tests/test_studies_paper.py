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
        if dist == "undistorted":  # A7: circular below diagonal by 1.5 mm
            err[("aruco", dist, traj, mode)] = 0.005 if traj == "circular" else 0.0065
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
    assert list(dict.fromkeys(claims["id"])) == ["S1", "S2", "S3", "S4", "S5", "A1", "A2", "A3", "A4", "A5", "A6",
                                                 "A7"]
    assert len(claims) == 29
    assert (claims["verdict"] == stats.HOLDS).all(), claims[claims["verdict"] != stats.HOLDS]
    assert (claims["n"] == 10).all()
    # one family (docs/design.md, "Multiplicity"): 29 wide effects stay decisive after Holm
    assert (claims["verdict_holm"] == stats.HOLDS).all() and (claims["p_holm"] >= claims["p_value"]).all()


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
        ("A7", {("aruco", "undistorted", "circular", "passive", "mean_abs_error_m"): 0.009}),
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
    assert set(paper.check_claims(df[df.target == "aruco"])["id"]) == {"A2", "A3", "A4", "A5", "A6", "A7"}


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
    assert [p.name for p in written] == ["sphere.mp4", "sphere.json", "aruco.mp4", "aruco.json"]
    for path in written[::2]:
        cap = cv2.VideoCapture(str(path))
        frames, width = int(cap.get(cv2.CAP_PROP_FRAME_COUNT)), int(cap.get(cv2.CAP_PROP_FRAME_WIDTH))
        cap.release()
        assert (frames, width) == (cell[0].n_frames, 2 * cell[0].camera.width + 4)
        info = probe_video(path)  # what a browser plays
        assert (info.codec, info.pixel_format, info.frames) == ("h264", "yuv420p", cell[0].n_frames)
    # a target whose pair is missing gets no clip (e.g. a study run for one target)
    assert paper.write_clips(tmp_path / "none", results[:1], study) == []


def test_a_clip_whose_runs_are_unchanged_is_copied_not_rendered(tmp_path, monkeypatch):
    """write_clips(previous=...) copies an earlier report's clip when its runs' store keys match and
    its bytes match its sidecar's digest; anything else renders it again."""
    import hashlib
    import json

    import gimbal_lab.show
    from gimbal_lab.runner import ResultsStore
    from gimbal_lab.simulation import simulate

    study = paper.PaperStudy(replicates=2, period_s=0.3)
    cell = [c for c in paper.grid(study, targets=("sphere",))
            if (c.camera.lens_label, c.target.trajectory, c.seed) == (*paper.CLIP_CELL, 0)]
    results = [simulate(c) for c in cell]
    first = tmp_path / "first"
    [clip, sidecar] = paper.write_clips(first, results, study)
    meta = json.loads(sidecar.read_text())
    by_mode = {r.config.pointing.mode: r for r in results}
    assert [run["store_key"] for run in meta["runs"]] == [ResultsStore.key(by_mode[m].config) for m in ("passive", "active")]
    assert meta["sha256"] == hashlib.sha256(clip.read_bytes()).hexdigest()

    rendered = []
    side_by_side = gimbal_lab.show.side_by_side

    def counting(passive, active, *args, **kwargs):
        rendered.append((passive.config.seed, active.config.seed))
        return side_by_side(passive, active, *args, **kwargs)

    monkeypatch.setattr(gimbal_lab.show, "side_by_side", counting)
    again = paper.write_clips(tmp_path / "again", results, study, previous=first)
    assert rendered == [] and again[0].read_bytes() == clip.read_bytes()
    assert json.loads(again[1].read_text()) == meta

    # another run in the pair (the same cell, seed 1 as first replicate): rendered again
    seed1 = paper.PaperStudy(replicates=2, period_s=0.3, first_seed=1)
    other = [simulate(c) for c in paper.grid(seed1, targets=("sphere",))
             if (c.camera.lens_label, c.target.trajectory, c.seed) == (*paper.CLIP_CELL, 1)]
    paper.write_clips(tmp_path / "other", other, seed1, previous=first)
    assert rendered == [(1, 1)]
    # a clip whose bytes no longer match its sidecar, or without a sidecar: rendered again
    with open(clip, "r+b") as f:
        f.seek(200)
        byte = f.read(1)
        f.seek(200)
        f.write(bytes([byte[0] ^ 1]))
    paper.write_clips(tmp_path / "damaged", results, study, previous=first)
    assert rendered == [(1, 1), (0, 0)]
    (tmp_path / "again" / "clips" / "sphere.json").unlink()  # an intact clip without its sidecar
    paper.write_clips(tmp_path / "no-sidecar", results, study, previous=tmp_path / "again")
    assert rendered == [(1, 1), (0, 0), (0, 0)]


# The whole report (tables, claims, figures, clips, metadata) as `gimbal-lab run paper` writes it
# is checked in tests/test_cli.py, on the same tiny grid, with the rerun that replaces it.


# ----------------------------------------------------------------------------------------------
# the strongest passive baseline: pipelines, BP1/BP2, claims.md as Markdown
# ----------------------------------------------------------------------------------------------
def test_pipeline_grid_is_the_distorted_cells_with_the_lens_known_and_the_best_estimator():
    study = paper.PaperStudy(replicates=3)
    configs = paper.pipeline_grid(study)
    assert len(configs) == 2 * 2 * 2 * 3 and len(set(configs)) == 24  # target × trajectory × mode × replicate
    study_runs = {(c.target.kind, c.target.trajectory, c.pointing.mode, c.seed): c for c in paper.grid(study)
                  if c.camera.lens_label == "distorted"}
    for c in configs:
        assert c.camera.lens_label == "distorted" and c.estimator.lens_strategy == "undistort"
        assert c.estimator.sphere_method == "ellipse"  # the exact cone fit is the sphere's primary
        assert not paper.is_study_run(c)
        twin = study_runs[(c.target.kind, c.target.trajectory, c.pointing.mode, c.seed)]
        # the same draws and loop as the study's run: only the estimator differs
        assert c.replace(estimator=twin.estimator) == twin
    assert all(paper.is_study_run(c) for c in paper.grid(study))
    with pytest.raises(ValueError, match="distorted camera only"):
        study.config("sphere", "undistorted", "circular", "active", 0, best=True)


def _fake_run(config, errors, detected=None, alt_errors=None, acquisition_error=1.0):
    """A finished run: revolution 0 with ``acquisition_error`` on every frame (which must never
    count), then the measured frames with the given errors (own and ``alt_``)."""
    from types import SimpleNamespace

    n = len(errors)
    detected = np.ones(n, bool) if detected is None else np.asarray(detected, bool)
    alt = np.asarray(errors if alt_errors is None else alt_errors, float)
    frames = pd.DataFrame({
        "frame": np.arange(2 * n), "revolution": np.repeat([0, 1], n),
        "detected": np.concatenate((np.ones(n, bool), detected)),
        "abs_error_m": np.concatenate((np.full(n, acquisition_error), errors)),
        "alt_detected": np.concatenate((np.ones(n, bool), detected)),
        "alt_abs_error_m": np.concatenate((np.full(n, acquisition_error), alt)),
        "offset_px": np.concatenate((np.full(n, 100.0), np.full(n, 5.0))),
    })
    return SimpleNamespace(config=config, frames=frames)


def test_pipeline_table_reads_each_pipeline_from_its_run_on_measured_common_frames():
    study = paper.PaperStudy(replicates=2)
    c = study.config
    runs = []
    for seed in (0, 1):
        # distorted: the paper's active run, and the two known-lens runs; the passive study run has no pipeline
        runs += [_fake_run(c("sphere", "distorted", "circular", "active", seed), [0.010, 0.020, 0.030, 0.040]),
                 _fake_run(c("sphere", "distorted", "circular", "passive", seed), [0.5] * 4),
                 _fake_run(c("sphere", "distorted", "circular", "active", seed, best=True), [0.002, 0.004, 0.006, 0.5],
                           detected=[1, 1, 1, 0]),
                 _fake_run(c("sphere", "distorted", "circular", "passive", seed, best=True),
                           [0.003, 0.006, 0.009, 0.012])]
        # undistorted: the study's runs hold the exact fit in alt_*
        runs += [_fake_run(c("sphere", "undistorted", "circular", "active", seed), [0.010] * 4, alt_errors=[0.001] * 4),
                 _fake_run(c("sphere", "undistorted", "circular", "passive", seed), [0.030] * 4, alt_errors=[0.004] * 4)]
    table = paper.pipeline_table(runs)
    assert len(table) == 2 * 2 * 3
    got = table.set_index(["distortion", "pipeline", "seed"])
    # distorted: frame 3 of the measured revolution is not detected by active (best): left out of every pipeline
    assert got.loc[("distorted", "active (paper)", 0), "common_abs_error_m"] == pytest.approx(0.020, rel=1e-12)
    assert got.loc[("distorted", "active (best)", 0), "common_abs_error_m"] == pytest.approx(0.004, rel=1e-12)
    assert got.loc[("distorted", "best passive", 1), "common_abs_error_m"] == pytest.approx(0.006, rel=1e-12)
    assert got.loc[("distorted", "active (paper)", 0), "common_rate"] == pytest.approx(0.75, rel=1e-12)
    assert got.loc[("distorted", "active (paper)", 0), "mean_abs_error_m"] == pytest.approx(0.025, rel=1e-12)
    # undistorted: the paper's pipeline is the circle method, the best ones the exact fit (alt_*)
    assert got.loc[("undistorted", "active (paper)", 0), "common_abs_error_m"] == pytest.approx(0.010, rel=1e-12)
    assert got.loc[("undistorted", "active (best)", 1), "common_abs_error_m"] == pytest.approx(0.001, rel=1e-12)
    assert got.loc[("undistorted", "best passive", 1), "common_abs_error_m"] == pytest.approx(0.004, rel=1e-12)
    # the acquisition revolution (1 m on every frame) never enters a mean
    assert (table["common_abs_error_m"] < 0.1).all() and (table["frames"] == 4).all()
    # a condition lacking a pipeline is left out; one with two runs for a pipeline is an error
    assert set(paper.pipeline_table([r for r in runs if not (r.config.estimator.lens_strategy == "undistort"
                                                             and r.config.pointing.active)])["distortion"]) \
        == {"undistorted"}
    with pytest.raises(ValueError, match="two runs for pipeline"):
        paper.pipeline_table(runs + runs[:1])


def make_pipelines(values, seeds=SEEDS, jitter=JITTER):
    """A pipeline table: per (target, distortion, trajectory, pipeline) a common-frame error + jitter."""
    rows = [dict(target=t, distortion=d, trajectory=tr, pipeline=p, seed=s, frames=60, detection_rate=1.0,
                 mean_abs_error_m=e + jitter[s], common_rate=1.0, common_abs_error_m=e + jitter[s], mean_offset_px=3.0)
            for (t, d, tr, p), e in values.items() for s in seeds]
    return pd.DataFrame(rows)


def test_bp_claims_on_hand_built_pipelines():
    replicates = make_replicates(paper_like_errors())
    values = {("sphere", "distorted", "circular", "active (paper)"): 0.050,
              ("sphere", "distorted", "circular", "active (best)"): 0.010,
              ("sphere", "distorted", "circular", "best passive"): 0.020}
    claims = paper.check_claims(replicates, make_pipelines(values))
    bp = claims[claims["id"].isin(["BP1", "BP2"])].set_index("id")
    assert len(claims) == 29 + 2
    # the paper's loop is worse than the best passive pipeline (30 mm); the best active is better (10 mm)
    assert bp.loc["BP1", "verdict"] == stats.DOES_NOT_HOLD and bp.loc["BP1", "difference"] == pytest.approx(0.030)
    assert bp.loc["BP2", "verdict"] == stats.HOLDS and bp.loc["BP2", "difference"] == pytest.approx(-0.010)
    assert bp.loc["BP2", "condition"] == "sphere, distorted, circular" and bp.loc["BP2", "b"] == "best passive"
    assert bp.loc["BP2", "verdict_holm"] == stats.HOLDS  # one family of 31, still decisive
    # a replicate without common frames (NaN) leaves its pair out
    pipes = make_pipelines(values)
    pipes.loc[(pipes.pipeline == "best passive") & (pipes.seed == 3), "common_abs_error_m"] = np.nan
    assert set(paper.check_claims(replicates, pipes).query("id == 'BP2'")["n"]) == {9}
    with pytest.raises(ValueError, match="lacks pipeline"):
        paper.check_claims(replicates, pipes[pipes.pipeline != "best passive"])


def _table_rows(text):
    """Every table of ``text`` parsed by markdown-it (CommonMark with the GFM table rule): a list
    of (header cells, body rows of cells, source lines of the table)."""
    from markdown_it import MarkdownIt

    tokens = MarkdownIt("commonmark").enable("table").parse(text)
    tables, current, row, in_head = [], None, None, False
    for tok in tokens:
        if tok.type == "table_open":
            current = {"head": None, "rows": [], "lines": tok.map}
        elif tok.type == "thead_open":
            in_head = True
        elif tok.type == "thead_close":
            in_head = False
        elif tok.type == "tr_open":
            row = []
        elif tok.type == "inline" and row is not None:
            row.append(tok.content)
        elif tok.type == "tr_close":
            if in_head:
                current["head"] = row
            else:
                current["rows"].append(row)
            row = None
        elif tok.type == "table_close":
            tables.append(current)
    return tables


def test_claims_md_tables_parse_with_one_cell_per_column_and_a6_rows_differ():
    """claims.md through a real Markdown parser: each row of the verdict table has exactly the
    header's cells (a ``|`` in ``|gap|`` or ``max(|err x|, |err y|)`` would split a cell: the
    parser drops or pads cells silently, so each cell is checked against the verdict it shows),
    and the two A6 rows (world y, world z) read differently."""
    change = {("sphere", "distorted", "circular", "active", "mean_abs_error_m"): 0.001}
    df = make_replicates(paper_like_errors(), change)
    values = {("sphere", "distorted", "circular", p): e for p, e in zip(paper.PIPELINES, (0.05, 0.01, 0.02))}
    claims = paper.check_claims(df, make_pipelines(values))
    text = paper.claims_markdown(claims, df, paper.PaperStudy())
    tables = _table_rows(text)
    verdict_table = tables[0]
    head = verdict_table["head"]
    assert head[-3:] == ["verdict", "p (Holm)", "verdict (Holm)"] and head[head.index("p (Holm)") - 2] == "p"
    start, stop = verdict_table["lines"]
    source = text.splitlines()[start:stop]
    assert len(verdict_table["rows"]) == len(claims) == len(source) - 2  # every line became one row
    col = {name: i for i, name in enumerate(head)}
    for cells, row in zip(verdict_table["rows"], claims.itertuples()):
        # the parser keeps the header's count, so a split cell shows as a wrong value in a column
        assert [cells[col[k]] for k in ("id", "claim", "condition", "a", "b")] == \
            [row.id, row.statement, row.condition, row.a, row.b]
        assert cells[col["p"]] == paper.format_p(row.p_value) and cells[col["p (Holm)"]] == paper.format_p(row.p_holm)
        assert cells[col["verdict"]] == f"**{row.verdict}**"
        assert cells[col["verdict (Holm)"]] == f"**{row.verdict_holm}**"
        # and, counted on the source line with escaped pipes honoured, exactly the header's cells
        line = source[2 + row.Index]
        assert len(line.replace("\\|", "").strip().strip("|").split("|")) == len(head)
    assert any("|gap|" in r.a for r in claims.itertuples())  # the escape is exercised
    a6 = [tuple(cells[col[k]] for k in ("claim", "condition", "a", "b")) for cells in verdict_table["rows"]
          if cells[col["id"]] == "A6"]
    assert len(a6) == 2 and a6[0] != a6[1] and "world y" in " ".join(a6[0]) and "world z" in " ".join(a6[1])
    for table in tables:  # the count table and the pipelines' table: every row has the header's cells
        start, stop = table["lines"]
        for line in text.splitlines()[start:stop]:
            assert len(line.replace("\\|", "").strip().strip("|").split("|")) == len(table["head"]), line
    assert "At the family level (Holm" in text


def test_forest_plot_labels_tell_the_a6_rows_apart():
    import matplotlib

    matplotlib.use("Agg")
    from gimbal_lab import plotting

    claims = paper.check_claims(make_replicates(paper_like_errors()))
    ax = plotting.study.plot_forest(claims)
    labels = [t.get_text() for t in ax.get_yticklabels() if t.get_text().startswith("A6")]
    assert len(labels) == 2 and labels[0] != labels[1]
    assert any("world y" in s for s in labels) and any("world z" in s for s in labels)
    import matplotlib.pyplot as plt

    plt.close("all")


def test_cpu_seconds_per_frame_times_every_frame_each_pass_and_refuses_bad_input():
    from gimbal_lab.studies import _params

    calls = []
    images = [np.zeros((4, 4))] * 3
    cost = _params.cpu_seconds_per_frame(calls.append, images, repeats=4)
    assert len(calls) == 12 and cost >= 0.0
    with pytest.raises(ValueError, match="images"):
        _params.cpu_seconds_per_frame(calls.append, [])
    for bad in (0, 1.5, True):
        with pytest.raises(ValueError, match="repeats"):
            _params.cpu_seconds_per_frame(calls.append, images, repeats=bad)


def test_pipeline_costs_time_every_kth_measured_frame_of_both_runs(monkeypatch):
    """``every`` (the notebooks' test size) times frames start, start + k, … of the measured
    revolution of the passive and the active run, the very frames the runs saw; 1 times them all."""
    from gimbal_lab.simulation import simulate
    from gimbal_lab.studies import _params

    study = paper.PaperStudy(replicates=2, period_s=0.3)  # 9 frames a revolution, 18 a run
    runs = [simulate(study.config("sphere", "distorted", "circular", mode, 0)) for mode in paper.MODES]
    all_frames = [_params.run_frames(r) for r in runs]
    timed = []
    monkeypatch.setattr(_params, "cpu_seconds_per_frame", lambda estimate, images, repeats: timed.append(images) or 1e-3)
    for every, per_run in ((4, [9, 13, 17]), (1, list(range(9, 18)))):
        timed.clear()
        costs = paper.pipeline_costs(runs, repeats=1, every=every)
        expected = [frames[i] for frames in all_frames for i in per_run]
        assert (costs["frames"] == 2 * len(per_run)).all() and len(timed) == 2  # the circle method, the cone fit
        for images in timed:
            assert len(images) == len(expected) and all(np.array_equal(a, b) for a, b in zip(images, expected))
    for bad, error in ((0, ValueError), (1.5, ValueError), (True, TypeError)):
        with pytest.raises(error, match="every"):
            paper.pipeline_costs(runs, repeats=1, every=bad)


def test_all_configs_are_the_grid_and_the_pipelines_runs():
    from gimbal_lab.studies import moving_drone as md

    study = paper.PaperStudy(replicates=2)
    assert paper.all_configs(study) == paper.grid(study) + paper.pipeline_grid(study)
    assert len(paper.all_configs(study)) == 16 * 2 + 8 * 2
    drone = md.MovingDroneStudy(replicates=2)
    assert len(md.all_configs(drone)) == 36 * 2 + 24 * 2


def test_an_estimator_built_without_the_other_localiser_gives_the_same_estimate():
    """What pipeline_costs times: Estimator.build(alt=False) runs one localiser, with the same result."""
    from gimbal_lab.config import Estimator
    from gimbal_lab.simulation import simulate
    from gimbal_lab.studies._params import run_frames

    study = paper.PaperStudy(replicates=2, period_s=0.3)
    c = study.config("sphere", "distorted", "circular", "passive", 0)
    images = run_frames(simulate(c), 9, 12)
    best = Estimator(sphere_method="ellipse", lens_strategy="undistort")
    both, alone = best.build(c.camera, c.target), best.build(c.camera, c.target, alt=False)
    for image in images:
        (px_a, p_a, other_a), (px_b, p_b, other_b) = both(image), alone(image)
        assert np.array_equal(px_a, px_b) and np.array_equal(p_a, p_b)
        assert other_a is not None and other_b is None
