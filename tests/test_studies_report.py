"""The report writer every study feeds (gimbal_lab.studies.report): the files it writes and their
bytes, the forest plot, a measurement kept once per set of runs, and the terminal's summary.

No closed-loop run is computed here: the reports are made of small tables written out by hand."""

from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest

from gimbal_lab import stats
from gimbal_lab.runner import ResultsStore, source_hash
from gimbal_lab.studies import report
from gimbal_lab.studies.paper import PaperStudy


def verdicts() -> pd.DataFrame:
    """Three conditions worked out by hand: C1 holds (a is 10 mm below b in every pair, δ = 1 mm),
    C2 does not hold (a is 10 mm above b), C3 is inconclusive (differences of ±20 mm straddle 0)."""
    b = np.full(6, 0.100)
    rows = [dict(id="C1", statement="a < b", condition="one", a="active", b="passive",
                 result=stats.less_than(b - 0.010 + 1e-4 * np.arange(6), b)),
            dict(id="C2", statement="a < b", condition="two", a="active", b="passive",
                 result=stats.less_than(b + 0.010 + 1e-4 * np.arange(6), b)),
            dict(id="C3", statement="a < b", condition="three", a="active", b="passive",
                 result=stats.less_than(b + np.array([0.02, -0.02, 0.02, -0.02, 0.02, -0.02]), b))]
    return stats.holm(stats.verdict_table(rows))


def a_report(table=None, figures=None, **kwargs) -> report.Report:
    import matplotlib.figure

    table = pd.DataFrame({"cell": ["x", "y"], "error_m": [0.1234567890123, 0.5]}) if table is None else table

    def line():
        fig = matplotlib.figure.Figure()
        fig.add_subplot().plot([0, 1, 2], [0.0, 1.0, 0.5], label="a line")
        return fig

    return report.Report("paper", PaperStudy(replicates=2), 7,
                         [("summary.csv", table), ("replicates.parquet", table), ("claims.md", "# claims\n")],
                         [("line", line)] if figures is None else figures, verdicts(), **kwargs)


def test_the_writer_puts_tables_text_metadata_then_figures_with_the_forest_last(tmp_path):
    """Each table as pandas writes it without its index (CSV text and Parquet content compared with
    pandas' own), the text as given, study.json with the study, its parameters and the package's
    source hash, then every figure in each format, the forest plot last."""
    rep = a_report()
    written = report.write(tmp_path, rep)
    names = [p.relative_to(tmp_path).as_posix() for p in written]
    assert names == ["summary.csv", "replicates.parquet", "claims.md", "study.json", "figures/line.png",
                     "figures/line.svg", "figures/hypotheses_forest.png", "figures/hypotheses_forest.svg"]
    table = rep.files[0][1]
    assert (tmp_path / "summary.csv").read_text() == table.to_csv(index=False)
    pd.testing.assert_frame_equal(pd.read_parquet(tmp_path / "replicates.parquet"), table)
    assert (tmp_path / "claims.md").read_text() == "# claims\n"
    meta = json.loads((tmp_path / "study.json").read_text())
    assert meta == {"study": "paper", "parameters": PaperStudy(replicates=2).to_dict(),
                    "package_version": meta["package_version"], "source_hash": source_hash(), "runs": 7}
    assert (tmp_path / "figures" / "hypotheses_forest.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_the_forest_shows_its_rows_and_is_left_out_without_verdicts(tmp_path):
    rep = a_report(figures=[], forest="claims_forest")
    assert [name for name, _ in rep.all_figures()] == ["claims_forest"]
    assert [name for name, _ in a_report(figures=[], forest=None).all_figures()] == []
    empty = a_report(figures=[], forest_rows=verdicts().iloc[:0])
    assert empty.all_figures() == []
    written = report.write(tmp_path, empty)
    assert not any(p.parent.name == "figures" for p in written)


def test_the_same_report_written_twice_is_the_same_bytes(tmp_path):
    """Every file, the SVG figures included (matplotlib stamps an SVG with the date and gives its
    clip paths random ids unless told otherwise)."""
    first, second = tmp_path / "first", tmp_path / "second"
    report.write(first, a_report())
    report.write(second, a_report())
    files = sorted(p.relative_to(first) for p in first.rglob("*") if p.is_file())
    assert len(files) == 8
    for name in files:
        assert (first / name).read_bytes() == (second / name).read_bytes(), name
    assert b"<dc:date>" not in (first / "figures" / "line.svg").read_bytes()


def test_the_forest_plots_caption_says_where_each_kind_of_claim_holds():
    """"a < b" always; "a ≤ b" and "a ≈ b" (inside the band, not merely near 0) when the table has them."""
    from gimbal_lab.plotting.study import plot_forest

    v = verdicts()
    assert "“a ≈ b”" not in plot_forest(v).get_xlabel() and "“a ≤ b”" not in plot_forest(v).get_xlabel()
    v.loc[0, "kind"], v.loc[1, "kind"] = "equivalent", "non-inferior"
    label = plot_forest(v).get_xlabel()
    assert "claim “a < b” holds left of −1" in label and "“a ≤ b”, at least as good, where the interval ends left of +1" \
        in label and "“a ≈ b” where the interval (90 %) lies inside ±1" in label


def test_a_table_with_another_suffix_is_refused(tmp_path):
    rep = a_report()
    rep.files.append(("table.xlsx", rep.files[0][1]))
    with pytest.raises(ValueError, match="a report table is written as .csv or .parquet, got table.xlsx"):
        report.write(tmp_path, rep)


# ----------------------------------------------------------------------------------------------
# the terminal's summary
# ----------------------------------------------------------------------------------------------
def test_the_summary_gives_the_tally_at_both_levels_what_fails_and_where_claims_md_is(tmp_path):
    v = verdicts()
    assert list(v["verdict"]) == [stats.HOLDS, stats.DOES_NOT_HOLD, stats.INCONCLUSIVE]
    lines = report.summary_lines(v, tmp_path / "claims.md")
    family = ", ".join(f"{(v['verdict_holm'] == x).sum()} {x}" for x in stats.VERDICTS)
    assert lines[0] == ("Of 3 conditions, at 95 % each: 1 holds, 1 does not hold, 1 inconclusive. At the family "
                        f"level (Holm's step-down over these 3 verdicts, 5 % family-wise error): {family}.")
    assert lines[1] == "Not holding or inconclusive at 95 %:"
    assert lines[2].startswith("  C2 two: active vs passive: does not hold; ")
    assert lines[3].startswith("  C3 three: active vs passive: inconclusive; ")
    assert lines[4:] == [f"Claims, reasons and every table: {tmp_path / 'claims.md'}"]


def test_the_summary_lists_a_few_conditions_and_counts_the_rest(tmp_path):
    many = pd.concat([verdicts().iloc[[1]]] * 11, ignore_index=True)
    lines = report.summary_lines(many, "claims.md", most=8)
    assert lines[1] == "Not holding or inconclusive at 95 % (the first 8):"
    assert len([line for line in lines if line.startswith("  C2")]) == 8
    assert lines[-2:] == ["  ... and 3 more", "Claims, reasons and every table: claims.md"]
    assert report.summary_lines(verdicts().iloc[:0], "claims.md")[0].startswith("No hypotheses to check")


# ----------------------------------------------------------------------------------------------
# a measurement kept once per set of runs
# ----------------------------------------------------------------------------------------------
def runs(*keys):
    return [SimpleNamespace(config=SimpleNamespace(key={"run": k})) for k in keys]


def test_a_measurement_is_made_once_per_set_of_runs_and_kept_with_its_machine(tmp_path):
    store = ResultsStore(tmp_path / "store")
    calls = []

    def measure():
        calls.append(1)
        return pd.DataFrame({"pipeline": ["a", "b"], "cost_ms": [2.468 + len(calls), 0.1]})

    first = report.measured_once(store, runs(1, 2), "cost", measure)
    again = report.measured_once(store, runs(2, 1), "cost", measure)  # the same runs in another order
    assert len(calls) == 1
    pd.testing.assert_frame_equal(again, first)
    sidecar, = (tmp_path / "store" / report.MEASUREMENTS).glob("*.json")
    meta = json.loads(sidecar.read_text())
    assert meta["what"] == "cost" and meta["runs"] == 2 and meta["machine"] == report.machine()
    report.measured_once(store, runs(1, 3), "cost", measure)  # other runs
    report.measured_once(store, runs(1, 2), "cost, least of 1 pass", measure)  # another measurement
    assert len(calls) == 3
    report.measured_once(ResultsStore(tmp_path / "store", read=False), runs(1, 2), "cost", measure)  # --no-cache
    assert len(calls) == 4
    table = sidecar.with_suffix(".parquet")
    pd.DataFrame({"pipeline": ["z"], "cost_ms": [0.0]}).to_parquet(table)  # another table in its place: not read
    assert report.measured_once(store, runs(1, 2), "cost", measure)["cost_ms"][0] == 2.468 + 5
    assert len(calls) == 5
    report.measured_once(None, runs(1, 2), "cost", measure)  # no store: measured, kept nowhere
    assert len(calls) == 6 and len(list((tmp_path / "store" / report.MEASUREMENTS).glob("*.json"))) == 3
